"""Benchmark: ``nbvdata generate`` with set-cover labels (``oracle.cover: true``) against the default.

For each mesh both jobs run in this process, one after the other (so a busy machine slows both
alike), one worker each, into temporary folders: the default settings, then the same with
``oracle.cover=true``. It prints each mesh's two wall times, then the whole set's: the ratio of
the totals, the share of labels proved optimal, and the seconds per label by step (the mesh's own
cover, solved once per mesh, apart).

    python benchmarks/cover.py [--meshes ../shared/meshes/train] [--skip N] [--limit N] [--set key=value ...]

Targets (issues 26, 50): with covers in <= 5x the default's time, and >= 99 % of the labels proved
optimal within ``oracle.cover_node_limit`` branch-and-bound nodes per state (a count, so the labels
do not depend on the machine's speed; the times do).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.generate import generate
from nbvdata.schema.shards import Shard
from nbvdata.simulation.sources import mesh_sources

TRAIN = Path(__file__).resolve().parents[2] / "shared" / "meshes" / "train"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", type=Path, default=TRAIN, help="folder of meshes (default the shared train/)")
    parser.add_argument("--skip", type=int, default=0, help="leave out the first N meshes (sorted by path)")
    parser.add_argument("--limit", type=int, help="then only the next N meshes")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="settings of both jobs, e.g. --set episode.runs_per_mesh=5")
    args = parser.parse_args()
    sources, failures = mesh_sources(args.meshes)
    sources = sources[args.skip:args.skip + args.limit if args.limit else None]
    plain = load_config(SimConfig, None, [*args.overrides, "generate.workers=1"])
    cover = load_config(SimConfig, None, [*args.overrides, "generate.workers=1", "oracle.cover=true"])
    print(f"{len(sources)} meshes from {args.meshes}, {plain.episode.runs_per_mesh} runs each, one worker; "
          f"cover node limit {cover.oracle.cover_node_limit:,} per state")
    print(f"{'mesh':44s} {'default s':>9s} {'cover s':>8s} {'ratio':>6s} {'labels':>6s} {'proved':>7s} "
          f"{'mesh cover s':>12s}")
    totals = {"default": 0.0, "cover": 0.0, "mesh": 0.0}
    by_step, proved, labels = defaultdict(list), 0, 0
    with tempfile.TemporaryDirectory() as folder:
        for number, source in enumerate(sources):
            seconds = {}
            for name, config in (("default", plain), ("cover", cover)):
                out = Path(folder) / name / str(number)
                started = time.perf_counter()
                report = generate([source], out, config, show_progress=False)
                seconds[name] = time.perf_counter() - started
                if report.failures:
                    print(f"{source.name[:44]:44s} failed: {report.failures[0][1]}")
                    break
            else:
                (result,) = report.done
                for step, spent in result.cover_seconds:
                    by_step[step].append(spent)
                mesh_seconds = result.seconds.get("cover_mesh", 0.0)
                with Shard(out / result.unit.shard_name) as shard:
                    done = int((shard["cover_bound"] == shard["cover_size"]).sum())
                    proved, labels = proved + done, labels + len(shard)
                totals["default"] += seconds["default"]
                totals["cover"] += seconds["cover"]
                totals["mesh"] += mesh_seconds
                print(f"{source.name[:44]:44s} {seconds['default']:9.1f} {seconds['cover']:8.1f} "
                      f"{seconds['cover'] / seconds['default']:5.1f}x {len(shard):6d} "
                      f"{100 * done / max(len(shard), 1):6.1f}% {mesh_seconds:12.2f}", flush=True)
    if not labels:
        raise SystemExit("no labels made")
    print(f"\nall: default {totals['default']:.0f} s, with covers {totals['cover']:.0f} s = "
          f"{totals['cover'] / totals['default']:.1f}x (target <= 5x); {labels} labels, "
          f"{100 * proved / labels:.2f} % proved optimal (target >= 99 %); meshes' own covers {totals['mesh']:.0f} s")
    print(f"\n{'step':>4s} {'labels':>7s} {'mean s':>8s} {'median s':>9s} {'max s':>7s}")
    for step in sorted(by_step):
        spent = by_step[step]
        print(f"{step:4d} {len(spent):7d} {np.mean(spent):8.3f} {statistics.median(spent):9.3f} {max(spent):7.2f}")
    if failures:
        print(f"{len(failures)} mesh files could not be read")


if __name__ == "__main__":
    main()
