"""Benchmark: ``nbvdata import-legacy`` of the authors' whole dataset, straight from the zips.

Imports the 15,166 rows of ``../shared/datasets/nbv-regression-2019`` into a temporary folder
and prints rows/s, wall time, peak memory (RSS) and the size of the shards, then the derived
runs: how many, and how many runs have each number of steps.

    python benchmarks/legacy_import.py [--rows-per-shard 2048] [--limit N]
"""

from __future__ import annotations

import argparse
import resource
import tempfile
from collections import Counter
from pathlib import Path

from nbvdata.datasets.authors import import_legacy

DATASET = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "nbv-regression-2019"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows-per-shard", type=int, default=2048)
    parser.add_argument("--limit", type=int, help="import only the first N rows")
    args = parser.parse_args()
    if not DATASET.exists():
        raise SystemExit(f"authors' dataset not found at {DATASET}")
    imports = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    with tempfile.TemporaryDirectory(prefix="nbv-legacy-") as out:
        report = import_legacy(DATASET / "dataset_volumes_regression.zip", DATASET / "dataset_pose.zip", Path(out),
                               args.rows_per_shard, args.limit, show_progress=False)
        size = sum(p.stat().st_size for p in Path(out).glob("*.h5"))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{report.rows:,} rows in {len(report.written)} shards in {report.seconds:.1f} s = "
          f"{report.rows / report.seconds:.0f} rows/s; peak RSS {peak:.0f} MiB ({imports:.0f} MiB before "
          f"importing: numpy, h5py, numba); "
          f"{size / 2**20:.1f} MiB of shards ({size / max(report.rows, 1) / 1024:.1f} KiB per row)")
    lengths = Counter(report.run_lengths)
    print(f"derived runs: {len(report.run_lengths):,}, {report.rows / len(report.run_lengths):.2f} steps per run "
          f"on average")
    print("steps per run: " + ", ".join(f"{steps}: {count}" for steps, count in sorted(lengths.items())))


if __name__ == "__main__":
    main()
