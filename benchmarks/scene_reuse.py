"""Benchmark: a ``generate.runs_per_shard=1`` job with and without reusing each mesh's scene.

The first ``--meshes`` built-in shapes at the default settings (500 views, 176 x 144 sensor,
16,384 reference points), ``--runs-per-mesh`` runs each, one shard per run, in this one process
(one worker). "before" casts the scene (500 noise-free scans, cast and matched) for every unit,
as ``nbvdata generate`` did before the scene cache (``SCENE_CACHE_SIZE = 0``); "after" casts it
once per mesh. The two jobs alternate ``--repeats`` times; medians are printed, and the shards of
the two are checked to be the same bytes.

    python benchmarks/scene_reuse.py [--meshes 3] [--runs-per-mesh 4] [--repeats 3]
"""

from __future__ import annotations

import argparse
import hashlib
import statistics
import tempfile
import time
from pathlib import Path

import nbvdata.datasets.generate as job
from nbvdata.core.config import SimConfig, load_config
from nbvdata.simulation.sources import builtin_sources


def _job(config: SimConfig, sources: list, cache_size: int) -> tuple[float, float, dict[str, str]]:
    """(wall seconds, seconds in the scene phase, shard sha256s) of one job from a cold cache."""
    job.clear_scene_caches(cache_size)
    with tempfile.TemporaryDirectory(prefix="nbv-scene-reuse-") as out:
        started = time.perf_counter()
        report = job.generate(sources, Path(out), config, show_progress=False)
        wall = time.perf_counter() - started
        digests = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(Path(out).glob("*.h5"))}
    if report.failures:
        raise SystemExit(f"meshes failed: {report.failures}")
    return wall, sum(r.seconds.get("scene", 0.0) for r in report.done), digests


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", type=int, default=3)
    parser.add_argument("--runs-per-mesh", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    config = load_config(SimConfig, None, ["generate.workers=1", "generate.runs_per_shard=1",
                                           f"episode.runs_per_mesh={args.runs_per_mesh}"])
    sources = builtin_sources(config.mesh)[:args.meshes]
    times: dict[str, list[tuple[float, float]]] = {"before": [], "after": []}
    digests, reuse = {}, job.SCENE_CACHE_SIZE
    for _ in range(args.repeats):
        for label, size in (("before", 0), ("after", reuse)):
            wall, scene, digests[label] = _job(config, sources, size)
            times[label].append((wall, scene))
    if digests["before"] != digests["after"]:
        raise SystemExit("the shards differ with and without reuse")
    print(f"{args.meshes} meshes x {args.runs_per_mesh} runs, one shard per run, one process; "
          f"medians of {args.repeats}:")
    print("| job | wall s | scene s |\n|---|---|---|")
    for label, pairs in times.items():
        print(f"| {label} | {statistics.median(w for w, _ in pairs):.1f} | "
              f"{statistics.median(s for _, s in pairs):.1f} |")
    before, after = (statistics.median(w for w, _ in times[k]) for k in ("before", "after"))
    print(f"speed-up {before / after:.2f}x; {len(digests['after'])} shards, the same bytes")


if __name__ == "__main__":
    main()
