"""Benchmark: ``nbvtrain evaluate --workers 2`` against one worker, in the same process.

The ten shared test meshes (or the built-in shapes when ../shared is absent), every planner that
needs no checkpoint of yours (the released score and regression networks, information gain, the
oracle, random), ``--starts 2``, default settings. The two jobs alternate ``--repeats`` times; the
figures are medians. The rows of coverage.csv must be the same with 1 and 2 workers but for the
seconds column (checked).

    python benchmarks/evaluate_workers.py [--repeats 2] [--workers 2] [--starts 2]

Target (issue 16): >= 1.6x faster with 2 workers than with 1 on an idle 2-core machine.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from nbvdata.config import SimConfig
from nbvdata.generate import builtin_sources, mesh_sources
from nbvdata.views import view_sphere
from nbvtrain.evaluate import evaluate
from nbvtrain.planners import build_planners

TEST_MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes" / "test"
PLANNERS = ["scores", "regression", "infogain", "oracle", "random"]


def _rows_without_seconds(rows: list[dict]) -> list[tuple]:
    return [tuple((key, value) for key, value in row.items() if key != "seconds") for row in rows]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2, help="alternated pairs of jobs")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--starts", type=int, default=2)
    args = parser.parse_args()
    if TEST_MESHES.is_dir():
        sources, failures = mesh_sources(TEST_MESHES)
        if failures:
            raise SystemExit(f"unreadable meshes: {failures}")
    else:
        print(f"{TEST_MESHES} absent: benchmarking the built-in shapes instead")
        sources = builtin_sources()
    config = SimConfig()
    planners, skipped = build_planners(PLANNERS, config, view_sphere(config.views), {})
    for message in skipped:
        print(message)
    print(f"{len(sources)} meshes x {len(planners)} planners x {1 + args.starts} starts, 10 scans, default settings")
    seconds: dict[int, list[float]] = {1: [], args.workers: []}
    reference = None
    for repeat in range(args.repeats):
        for workers in (1, args.workers):
            report = evaluate(sources, planners, config, scans=10, starts=args.starts, seed=1, workers=workers)
            if report.failures:
                raise SystemExit(f"meshes failed: {report.failures}")
            rows = _rows_without_seconds(report.rows)
            if reference is None:
                reference = rows
            elif rows != reference:
                raise SystemExit(f"{workers} worker(s) gave other coverage.csv rows than 1 worker")
            seconds[workers].append(report.seconds)
            print(f"  repeat {repeat + 1}: {workers} worker(s) {report.seconds:.1f} s")
    one, many = statistics.median(seconds[1]), statistics.median(seconds[args.workers])
    print(f"median wall time: 1 worker {one:.1f} s, {args.workers} workers {many:.1f} s: {one / many:.2f}x "
          f"(target >= 1.6x); the coverage.csv rows are the same but for the seconds column")


if __name__ == "__main__":
    main()
