"""A ranker on its own states: how much of the best valid gain its choice keeps, by scan step, on
the states it reaches itself, beside ``farthest``'s choice on those same states and its own on the
oracle's path (issue 63's diagnosis of a DAgger round; the closed loop's AUC decides, this says why).

For every mesh and start (``nbvtrain benchmark``'s start views of the protocol), each ranker plays
its own reconstruction; at every state the exact scores (``nbvdata.simulation.oracle``) give the valid gain of
the view it chooses over the best valid gain (1: the oracle's choice; a state with no valid view
adding anything is left out), and the same for ``farthest``'s choice there. Then the oracle plays,
and each ranker's choice on the oracle's states is scored the same way. The figures are means over
states, by scan step (the scans taken before the choice) and overall.

    python benchmarks/ranker_states.py --ranker runs/r1/viewrank.json[,nbvtrain/released/viewrank.json] \\
        --manifest manifests/train-meshes-1.6.0.json --part val --meshes ../shared/meshes --limit 40 --starts 2

``--protocol`` (default paper) sets the views and the scans; ``--workers`` meshes at a time.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import numpy as np

from nbvdata.core.views import Pose, farthest_view
from nbvdata.simulation.episode import run_seed, scene_rng
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.sources import mesh_sources, part_sources
from nbvtrain.evaluation.benchmark import load_protocol, protocol_config, start_views_of
from nbvtrain.evaluation.evaluate import limit_threads, mesh_cache, reconstruct
from nbvtrain.planners import Observation, OraclePlanner, Planner, RankerPlanner

TARGET = "valid"  # --target: "valid" gains (the overlap rule's, the labels') or "all" (coverage alone)


def kept(truth, view: int) -> float | None:
    """The valid gain of ``view`` at ``truth``'s state over the best valid gain (with ``TARGET``
    "all": its gain over the best gain); None when no (valid) view adds anything."""
    scores = truth.scene.oracle.score(truth.covered)
    valid = scores.new > 0
    if TARGET == "valid":
        valid &= scores.overlaps >= truth.scene.config.oracle.min_overlap
    best = float(scores.gains[valid].max()) if valid.any() else 0.0
    if best <= 0:
        return None
    return float(scores.gains[view]) / best if valid[view] else 0.0


class Watching(Planner):
    """``planner`` played as it is, while at each state the choices of ``watched`` (name -> planner,
    each a ``candidate_scores`` planner, or "farthest") are scored with ``kept``, into ``records``:
    (name, scan step) -> ratios."""

    privileged = True

    def __init__(self, planner: Planner, watched: dict, views):
        self.planner, self.watched, self.views, self.name = planner, watched, views, planner.name
        self.records: dict[tuple[str, int], list[float]] = defaultdict(list)

    def start(self, seed) -> None:
        self.planner.start(seed)

    def next_pose(self, observation: Observation, truth=None) -> Pose:
        step = len(observation.poses)
        for name, watched in self.watched.items():
            if watched == "farthest":
                view = farthest_view(self.views.unit_positions, observation.positions)
            else:
                _, scores = watched.candidate_scores(observation)
                view = int(np.argmax(scores)) if np.isfinite(scores).any() else 0
            ratio = kept(truth, view)
            if ratio is not None:
                self.records[(name, step)].append(ratio)
        return self.planner.next_pose(observation, truth if self.planner.privileged else None)


def mesh_records(source, rankers: list[Path], config, protocol, starts: int, seed: int, target: str) -> dict:
    """Every ratio of one mesh: (what, ranker, step) -> ratios, ``what`` "own", "farthest" or "oracle path"."""
    global TARGET
    TARGET = target
    limit_threads(1)
    scene = Scene.build(source.load(config.mesh), config, scene_rng(seed, source.mesh_id), 1)
    planners = {path: RankerPlanner(path, scene.views, config, name=str(path)) for path in rankers}
    cache = mesh_cache(scene, list(planners.values()))
    out: dict[tuple[str, str, int], list[float]] = defaultdict(list)
    firsts = start_views_of(scene, source.mesh_id, protocol, starts, seed)
    for path, planner in planners.items():
        watching = Watching(planner, {"own": planner, "farthest": "farthest"}, scene.views)
        for number, first in enumerate(firsts):
            reconstruct(scene, watching, first, protocol.views, run_seed(seed, source.mesh_id, number), cache=cache)
        for (what, step), ratios in watching.records.items():
            out[(what, str(path), step)] += ratios
    oracle = Watching(OraclePlanner(scene.views, config.oracle.min_overlap), {str(p): q for p, q in planners.items()},
                      scene.views)
    for number, first in enumerate(firsts):
        reconstruct(scene, oracle, first, protocol.views, run_seed(seed, source.mesh_id, number), cache=cache)
    for (name, step), ratios in oracle.records.items():
        out[("oracle path", name, step)] += ratios
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ranker", required=True, help="ranker files, comma-separated")
    parser.add_argument("--manifest", type=Path)
    parser.add_argument("--part", default="val")
    parser.add_argument("--meshes", type=Path, default=Path("../shared/meshes"))
    parser.add_argument("--protocol", default="paper")
    parser.add_argument("--limit", type=int, default=40)
    parser.add_argument("--starts", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--target", choices=["valid", "all"], default="valid", help="score choices by valid gains "
                        "(default) or by every view's gain (the coverage the benchmark measures, no overlap rule)")
    args = parser.parse_args()
    global TARGET
    TARGET = args.target
    rankers = [Path(part) for part in args.ranker.split(",") if part]
    protocol = load_protocol(args.protocol)
    config = protocol_config(protocol, None, [])
    sources = (part_sources(args.manifest, args.part, args.meshes)[0] if args.manifest
               else mesh_sources(args.meshes)[0])[:args.limit]
    from joblib import Parallel, delayed

    results = Parallel(n_jobs=args.workers, backend="loky")(
        delayed(mesh_records)(source, rankers, config, protocol, args.starts, args.seed, args.target)
        for source in sources)
    merged: dict[tuple[str, str, int], list[float]] = defaultdict(list)
    for result in results:
        for key, ratios in result.items():
            merged[key] += ratios
    steps = sorted({step for _, _, step in merged})
    print(f"{len(sources)} meshes x {args.starts} starts, protocol {protocol.name}: mean share of the best "
          f"{'valid ' if args.target == 'valid' else ''}gain kept by the choice, by scans taken")
    print("| ranker | states | " + " | ".join(f"after {step}" for step in steps) + " | all |")
    print("|---|---|" + "---|" * (len(steps) + 1))
    for path in rankers:
        for what, label in (("own", "its choice, its states"), ("farthest", "farthest's choice, its states"),
                            ("oracle path", "its choice, the oracle's states")):
            rows = {step: merged.get((what, str(path), step), []) for step in steps}
            every = [ratio for ratios in rows.values() for ratio in ratios]
            cells = [f"{np.mean(rows[step]):.2f}" if rows[step] else "-" for step in steps]
            print(f"| {path.parent.name}/{path.name}: {label} | {len(every)} | " + " | ".join(cells)
                  + f" | {np.mean(every):.3f} |")


if __name__ == "__main__":
    main()
