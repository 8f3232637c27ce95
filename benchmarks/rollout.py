"""Benchmark: what exploration and learned-policy rollouts cost in ``nbvdata generate``.

The built-in shapes at the default settings (500 views, 176 x 144 sensor, 16,384 reference
points, up to 10 scans per run), ``--runs-per-mesh`` runs each, once per way of moving: the
oracle (today's data), exploration (``--explore``), and a policy per network (untrained, seeded
checkpoints of the size of a trained one; or ``--checkpoint`` for yours). Every job runs in one
process, one after the other, so the phases compare; the scene (the per-mesh precomputation) is
the same for all.

    python benchmarks/rollout.py [--runs-per-mesh 10] [--workers 1] [--explore 0.3]
        [--networks nbvnet-3-3 nbvnet-4-5] [--checkpoint runs/NAME/best.pt]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.generate import generate
from nbvdata.simulation.policy import PolicySource
from nbvdata.simulation.sources import builtin_sources


def _checkpoint(name: str, folder: Path) -> Path:
    import torch

    from nbvtrain.networks.config import TrainConfig
    from nbvtrain.networks.models import build_model
    from nbvtrain.networks.train import save_training_state

    torch.manual_seed(0)
    model = build_model(name)
    path = folder / f"{name}.pt"
    save_training_state(path, model, torch.optim.Adam(model.parameters()), TrainConfig(model=name), [], 0, 0.4)
    return path


def _job(label: str, config: SimConfig, policy: PolicySource | None = None) -> None:
    with tempfile.TemporaryDirectory(prefix="nbv-rollout-") as out:
        started = time.perf_counter()
        report = generate(builtin_sources(config.mesh), Path(out), config, show_progress=False, policy=policy)
        wall = time.perf_counter() - started
    if report.failures:
        raise SystemExit(f"meshes failed: {report.failures}")
    phases: dict[str, float] = defaultdict(float)
    for result in report.done:
        for phase, seconds in result.seconds.items():
            phases[phase] += seconds
    per_sample = 1e3 * phases["runs"] / max(report.samples, 1)
    print(f"| {label} | {report.samples} | {wall:.1f} | {report.samples / wall:.1f} | {phases['scene']:.1f} | "
          f"{phases['policy']:.1f} | {phases['runs']:.1f} | {per_sample:.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs-per-mesh", type=int, default=10)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--explore", type=float, default=0.3)
    parser.add_argument("--networks", nargs="*", default=["nbvnet-3-3", "nbvnet-4-5"])
    parser.add_argument("--checkpoint", type=Path, help="a trained checkpoint to follow instead of --networks")
    args = parser.parse_args()
    overrides = [f"episode.runs_per_mesh={args.runs_per_mesh}", f"generate.workers={args.workers}"]
    config = load_config(SimConfig, None, overrides)
    print("| moves | samples | wall s | samples/s | scene s | policy load s | runs s | runs ms/sample |")
    print("|---|---|---|---|---|---|---|---|")
    _job("oracle", config)
    _job(f"explore {args.explore:g}", load_config(SimConfig, None, overrides + [f"episode.explore={args.explore}"]))
    with tempfile.TemporaryDirectory(prefix="nbv-rollout-checkpoints-") as folder:
        paths = [args.checkpoint] if args.checkpoint else [_checkpoint(name, Path(folder)) for name in args.networks]
        for path in paths:
            policy = PolicySource.from_path(path)
            _job(f"policy {path.stem}", config, policy)


if __name__ == "__main__":
    main()
