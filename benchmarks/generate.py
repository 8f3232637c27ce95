"""Benchmark: a paper-scale dataset with ``nbvdata generate``, and where its time goes.

The twelve meshes of ``../shared/meshes/paper_train.txt``, the default settings (500 hemisphere
views, 176 x 144 sensor, 16,384 reference points, up to 10 scans per run) and enough runs per
mesh for >= 15,000 labelled states. The job runs with ``--workers`` workers, then (unless
``--no-baseline``) again with one worker in the same process: the ratio is the parallel speedup.

    python benchmarks/generate.py [--runs-per-mesh 200] [--workers 2] [--no-baseline]

Target: <= 180 s wall time on a 2-core machine.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.generate import Report, generate
from nbvdata.simulation.sources import builtin_sources, mesh_sources

PAPER_TRAIN = Path(__file__).resolve().parents[2] / "shared" / "meshes" / "paper_train.txt"


def _run(sources, config: SimConfig) -> tuple[Report, int]:
    """The job in a fresh temporary folder: its report and the bytes of shards written."""
    with tempfile.TemporaryDirectory(prefix="nbv-bench-") as out:
        report = generate(sources, Path(out), config, show_progress=False)
        size = sum(p.stat().st_size for p in Path(out).glob("*.h5"))
    if report.failures:
        raise SystemExit(f"meshes failed: {report.failures}")
    return report, size


def _print(label: str, report: Report, size: int) -> None:
    phases: dict[str, float] = defaultdict(float)
    for result in report.done:
        for phase, seconds in result.seconds.items():
            phases[phase] += seconds
    busy = sum(phases.values())
    print(f"{label}: {report.samples:,} states from {len(report.done)} meshes in {report.seconds:.1f} s wall "
          f"= {report.samples / report.seconds:.0f} states/s; {size / 2**20:.0f} MiB of shards "
          f"({size / max(report.samples, 1) / 1024:.1f} KiB per state)")
    print("  worker time: " + ", ".join(f"{phase} {seconds:.1f} s ({100 * seconds / busy:.0f}%)"
                                        for phase, seconds in phases.items())
          + f"; total {busy:.1f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs-per-mesh", type=int, default=200)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--no-baseline", action="store_true", help="skip the one-worker run")
    args = parser.parse_args()
    if PAPER_TRAIN.exists():
        sources, failures = mesh_sources(PAPER_TRAIN)
        if failures:
            raise SystemExit(f"unreadable meshes: {failures}")
    else:
        print(f"{PAPER_TRAIN} absent: benchmarking the built-in shapes instead")
        sources = builtin_sources()
    base = [f"episode.runs_per_mesh={args.runs_per_mesh}"]
    config = load_config(SimConfig, None, base + [f"generate.workers={args.workers}"])
    print(f"{len(sources)} meshes x {args.runs_per_mesh} runs, {config.views.count} views, "
          f"{config.sensor.width}x{config.sensor.height} sensor, up to {config.episode.max_scans} scans per run")
    start = time.perf_counter()
    report, size = _run(sources, config)
    _print(f"{args.workers} workers", report, size)
    verdict = "meets" if report.seconds <= 180 and report.samples >= 15_000 else "MISSES"
    print(f"  {verdict} the target: >= 15,000 states in <= 180 s")
    if not args.no_baseline:
        baseline, size = _run(sources, load_config(SimConfig, None, base + ["generate.workers=1"]))
        _print("1 worker ", baseline, size)
        if [r.samples for r in sorted(baseline.done, key=lambda r: r.unit.shard_name)] != \
                [r.samples for r in sorted(report.done, key=lambda r: r.unit.shard_name)]:
            raise SystemExit("the one-worker run labelled a different number of states")
        print(f"parallel speedup with {args.workers} workers: {baseline.seconds / report.seconds:.2f}x")
    print(f"benchmark total {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
