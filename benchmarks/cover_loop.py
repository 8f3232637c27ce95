"""scvp-net in closed loop: milliseconds per decision and network calls per reconstruction.

Issue 66: under load scvp-net took 488 ms a decision (15-39 ms idle): once no view reached the
threshold it asked the network again at every decision, for one view. Now a prediction with
nothing over the threshold is the plan for the rest of the run (``CoverPlanner.planned_set``).
This runs both rules on the same reconstructions, in one process, one thread: ``ask every
decision`` (the old rule, kept here as the baseline) and the planner as it is; with ``--load N``,
N processes spin beside it (a benchmark's other workers).

    python benchmarks/cover_loop.py --scvp-checkpoint runs/scvp-net/covernet.pt [--meshes DIR] [--scans 32] [--load 2]

Without ``--meshes``: the built-in shapes, in SCVP's 32 views.
"""

from __future__ import annotations

import argparse
import multiprocessing
import time
from pathlib import Path

import numba
import numpy as np
import torch

from nbvdata.core.config import SimConfig, load_config
from nbvdata.core.views import view_sphere
from nbvdata.simulation.sources import SceneCache, builtin_sources, mesh_sources
from nbvtrain.evaluation.evaluate import reconstruct
from nbvtrain.planners import SCVPNetPlanner, robot_radius


class AskEveryDecision(SCVPNetPlanner):
    """The rule before issue 66: nothing over the threshold plans the single most probable view."""

    def chosen(self, probabilities: np.ndarray) -> list[int]:
        return super().chosen(probabilities) or [int(np.argmax(probabilities))]


def _spin(stop) -> None:
    while not stop.is_set():
        sum(range(10_000))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scvp-checkpoint", type=Path, required=True)
    parser.add_argument("--meshes", type=Path)
    parser.add_argument("--scans", type=int, default=32)
    parser.add_argument("--load", type=int, default=0, help="busy processes beside the measurement")
    args = parser.parse_args()
    numba.set_num_threads(1)
    torch.set_num_threads(1)
    config = load_config(SimConfig, None, ["views.layout=scvp-32", "views.count=32"])
    views, radius = view_sphere(config.views), robot_radius(config)
    sources = mesh_sources(args.meshes)[0] if args.meshes else builtin_sources(config.mesh)
    stop = multiprocessing.Event()
    spinners = [multiprocessing.Process(target=_spin, args=(stop,), daemon=True) for _ in range(args.load)]
    for spinner in spinners:
        spinner.start()
    rules = {"ask every decision (baseline)": AskEveryDecision(args.scvp_checkpoint, views, radius),
             "one prediction serves the rest": SCVPNetPlanner(args.scvp_checkpoint, views, radius)}
    results = {name: ([], []) for name in rules}
    cache = SceneCache(1)
    started = time.perf_counter()
    for source in sources:
        _, scene, view_cache = cache.get(source, config, threads=1)
        for name, planner in rules.items():
            calls = [0]
            predict = planner.probabilities

            def counted(observation, predict=predict, calls=calls):
                calls[0] += 1
                return predict(observation)

            planner.probabilities = counted
            rows = reconstruct(scene, planner, 0, args.scans, 0, cache=view_cache)
            planner.probabilities = predict
            results[name][0].extend(1000 * row["seconds"] for row in rows[1:])
            results[name][1].append(calls[0])
    stop.set()
    print(f"{len(sources)} meshes x {args.scans} scans, SCVP's 32 views, one thread, {args.load} busy processes "
          f"beside, {time.perf_counter() - started:.0f} s")
    base = None
    for name, (ms, calls) in results.items():
        median = float(np.median(ms))
        base = base or median
        print(f"{name:32s} median {median:7.2f} ms a decision ({median / base:.2f}x), mean {np.mean(ms):6.2f} ms, "
              f"{np.mean(calls):.1f} network calls a reconstruction")


if __name__ == "__main__":
    main()
