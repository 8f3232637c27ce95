"""Benchmark: what the shards' checksums cost - size, writing, and reading every byte.

Shards of the built-in shapes at the default settings (the README's dataset; ``--points N``
adds N-point clouds) are made once; then each shard's arrays are written, alternately, as
``nbvdata.schema.shards.write_shard`` writes them (a Fletcher-32 checksum on every chunk, the per-shard
arrays one chunk each, the attributes' sha256) and as shards were written before issue 50 (no
checksums, per-shard arrays contiguous), ``--repeats`` times. Printed: total bytes of each, the
median seconds to write all shards, and to read every dataset of every shard whole (what
``Shard.check`` and ``nbvdata verify DIR`` do; with checksums HDF5 checks each chunk as it reads).

    python benchmarks/shard_integrity.py [--runs-per-mesh 20] [--points 0] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import h5py

from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.generate import generate
from nbvdata.schema.shards import ATTRIBUTES_DIGEST, PER_SAMPLE, PER_SHARD, SCHEMA_VERSION, Shard, write_shard
from nbvdata.simulation.sources import builtin_sources


def _without_checksums(path: Path, arrays: dict, attrs: dict) -> None:
    """A shard as ``write_shard`` wrote it before the checksums."""
    with h5py.File(path, "w", libver=("earliest", "v110")) as f:
        f.attrs["schema_version"] = SCHEMA_VERSION
        for key, value in attrs.items():
            f.attrs[key] = value
        for name in PER_SHARD:
            if name in arrays:
                f.create_dataset(name, data=arrays[name], track_times=False).flush()
        for name in PER_SAMPLE:
            if name in arrays:
                data = arrays[name]
                f.create_dataset(name, data=data, chunks=(1,) + data.shape[1:] if data.ndim > 1 else None,
                                 compression="gzip", compression_opts=4, track_times=False).flush()


def _read_all(paths: list[Path]) -> float:
    started = time.perf_counter()
    for path in paths:
        with h5py.File(path, "r") as f:
            for name in f:
                f[name][()]
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs-per-mesh", type=int, default=20)
    parser.add_argument("--points", type=int, default=0, help="state.points: clouds in the shards (default none)")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    config = load_config(SimConfig, None, [f"episode.runs_per_mesh={args.runs_per_mesh}", "generate.workers=1",
                                           f"state.points={args.points}"])
    with tempfile.TemporaryDirectory(prefix="nbv-integrity-") as folder:
        made = Path(folder) / "made"
        generate(builtin_sources(), made, config, show_progress=False)
        shards = []
        for path in sorted(made.glob("*.h5")):
            with Shard(path) as shard:
                arrays = {name: shard[name] for name in shard.file}
                attrs = {key: value for key, value in shard.file.attrs.items()
                         if key not in ("schema_version", ATTRIBUTES_DIGEST)}
            shards.append((path.name, arrays, attrs))
        writers = {"checksums": lambda p, a, t: write_shard(p, a, t), "none": _without_checksums}
        seconds = {name: {"write": [], "read": []} for name in writers}
        sizes = {}
        for _ in range(args.repeats):
            for name, write in writers.items():
                out = Path(folder) / name
                out.mkdir(exist_ok=True)
                started = time.perf_counter()
                for shard_name, arrays, attrs in shards:
                    write(out / shard_name, arrays, attrs)
                seconds[name]["write"].append(time.perf_counter() - started)
                paths = sorted(out.glob("*.h5"))
                seconds[name]["read"].append(_read_all(paths))
                sizes[name] = sum(p.stat().st_size for p in paths)
    samples = sum(len(arrays["nbv_index"]) for _, arrays, _ in shards)
    print(f"{len(shards)} shards, {samples} samples (built-in shapes, {args.runs_per_mesh} runs each, "
          f"state.points={args.points}); medians of {args.repeats}")
    print(f"{'':10s} {'bytes':>12s} {'write s':>8s} {'read s':>7s}")
    for name in writers:
        print(f"{name:10s} {sizes[name]:12,d} {statistics.median(seconds[name]['write']):8.3f} "
              f"{statistics.median(seconds[name]['read']):7.3f}")
    ratio = lambda key: statistics.median(seconds["checksums"][key]) / statistics.median(seconds["none"][key])  # noqa: E731
    print(f"checksums / none: size {sizes['checksums'] / sizes['none']:.4f}x, write {ratio('write'):.2f}x, "
          f"read {ratio('read'):.2f}x")


if __name__ == "__main__":
    main()
