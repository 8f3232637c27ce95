"""Benchmark: ``nbvtrain evaluate --workers 2`` against one worker, as a user runs it.

The ten shared test meshes (../shared/meshes/test, required), every planner that
needs no checkpoint of yours (the released score and regression networks, information gain, the
oracle, random), ``--random-starts 2 --seed 1``, default settings. Each job is the command itself in a
fresh process (imports, starting the worker processes and building the planners included); the
two alternate ``--repeats`` times and the figures are medians. Their coverage.csv files must be
the same but for the seconds column (checked).

    python benchmarks/evaluate_workers.py [--repeats 2] [--workers 2] [--random-starts 2]

Target (issue 16): >= 1.6x faster with 2 workers than with 1 on an idle 2-core machine.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TEST_MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes" / "test"
PLANNERS = "scores,regression,infogain,oracle,random"


def _rows_without_seconds(path: Path) -> list[tuple]:
    with open(path, newline="") as f:
        return [tuple((key, value) for key, value in row.items() if key != "seconds") for row in csv.DictReader(f)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2, help="alternated pairs of jobs")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--random-starts", type=int, default=2)
    args = parser.parse_args()
    if not TEST_MESHES.is_dir():
        raise SystemExit(f"{TEST_MESHES} absent: this benchmark needs the shared test meshes")
    meshes = str(TEST_MESHES)
    print(f"nbvtrain evaluate --meshes {meshes} --planners {PLANNERS} --random-starts {args.random_starts} --seed 1, "
          f"1 against {args.workers} workers, each a fresh process")
    seconds: dict[int, list[float]] = {1: [], args.workers: []}
    reference = None
    with tempfile.TemporaryDirectory(prefix="nbv-bench-") as tmp:
        for repeat in range(args.repeats):
            for workers in (1, args.workers):
                out = Path(tmp) / f"{repeat}-{workers}"
                command = [sys.executable, "-m", "nbvtrain", "evaluate", "--meshes", meshes, "--planners", PLANNERS,
                           "--random-starts", str(args.random_starts), "--seed", "1", "--workers", str(workers),
                           "--out", str(out)]
                start = time.perf_counter()
                done = subprocess.run(command, capture_output=True, text=True)
                seconds[workers].append(time.perf_counter() - start)
                if done.returncode != 0:
                    raise SystemExit(f"{' '.join(command)} failed:\n{done.stderr[-2000:]}")
                rows = _rows_without_seconds(out / "coverage.csv")
                if reference is None:
                    reference = rows
                elif rows != reference:
                    raise SystemExit(f"{workers} worker(s) wrote other coverage.csv rows than 1 worker")
                print(f"  repeat {repeat + 1}: {workers} worker(s) {seconds[workers][-1]:.1f} s")
    one, many = statistics.median(seconds[1]), statistics.median(seconds[args.workers])
    print(f"median wall time: 1 worker {one:.1f} s, {args.workers} workers {many:.1f} s: {one / many:.2f}x "
          f"(target >= 1.6x); coverage.csv the same but for the seconds column")


if __name__ == "__main__":
    main()
