"""Benchmark: what recording a 10-scan run in Rerun (``nbvdata.view.rerun``) adds to the run.

For each built-in shape at the default settings (500 views, 176 x 144 sensor, 16,384 reference
points, 10 scans; ``episode.min_gain=0`` so that every run takes its 10 scans where any view still
adds a point), in this one process: the run alone (``run_reconstruction``, the way ``nbvdata
generate`` runs it), and the run then recorded to a new ``.rrd`` (``Recording`` + ``log_record`` +
``close``, the way ``--rerun-runs`` records it). The two alternate ``--repeats`` times after one
warm-up of each (the scene and its view cache are built before, not timed); medians are printed
with the difference, against the target of at most 1 s added per run.

    python benchmarks/rerun_cost.py [--repeats 5] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from nbvdata.core.config import SimConfig, load_config
from nbvdata.simulation.episode import ViewCache, run_reconstruction, run_seed, scene_rng, start_view
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.shapes import BUILTIN_SHAPES, builtin_object
from nbvdata.view.rerun import Recording, log_record

TARGET_SECONDS = 1.0


def _run(scene: Scene, cache: ViewCache, start: int, seed: int):
    return run_reconstruction(scene, start, np.random.default_rng(seed), cache)


def _recorded(scene: Scene, cache: ViewCache, start: int, seed: int, path: Path) -> int:
    """The run, then its recording; returns the number of states recorded."""
    record = _run(scene, cache, start, seed)
    with Recording(path, path.stem) as recording:
        log_record(recording.run(["run_0000"], scene), record)
    return len(record)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    config = load_config(SimConfig, None, ["episode.max_scans=10", "episode.min_gain=0", *args.overrides])
    print(f"one run of up to {config.episode.max_scans} scans per shape, {len(BUILTIN_SHAPES)} shapes; "
          f"medians of {args.repeats}, seconds:")
    print("| shape | states | run | run + recording | added | .rrd MB |\n|---|---|---|---|---|---|")
    added_all = []
    with tempfile.TemporaryDirectory(prefix="nbv-rerun-cost-") as folder:
        for name in BUILTIN_SHAPES:
            obj = builtin_object(name, config.mesh)
            scene = Scene.build(obj, config, scene_rng(config.episode.seed, obj.mesh_id))
            cache = ViewCache(scene)
            start = start_view(config.episode.seed, obj.mesh_id, len(scene.views), 0)
            seed = run_seed(config.episode.seed, obj.mesh_id, 0)
            path = Path(folder) / f"{name}.rrd"
            _recorded(scene, cache, start, seed, path)  # warm-up: view cache, first recording
            plain, recorded = [], []
            for _ in range(args.repeats):
                began = time.perf_counter()
                _run(scene, cache, start, seed)
                plain.append(time.perf_counter() - began)
                began = time.perf_counter()
                states = _recorded(scene, cache, start, seed, path)
                recorded.append(time.perf_counter() - began)
            run, both = statistics.median(plain), statistics.median(recorded)
            added_all.append(both - run)
            print(f"| {name} | {states} | {run:.3f} | {both:.3f} | {both - run:.3f} | "
                  f"{path.stat().st_size / 2 ** 20:.1f} |")
    worst = max(added_all)
    print(f"recording adds at most {worst:.3f} s per run (median over shapes {statistics.median(added_all):.3f} s): "
          f"{'within' if worst <= TARGET_SECONDS else 'OVER'} the target of {TARGET_SECONDS:g} s")


if __name__ == "__main__":
    main()
