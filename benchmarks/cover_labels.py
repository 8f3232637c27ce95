"""Label quality of the learned set covers on validation states (issue 57, item 5): for each state
of a cover version's validation meshes, the predicted set against the state's proved optimum -
its size, precision and recall of membership - and whether it *is* a cover: whether its views'
noise-free scans together reach every observable reference point the state has left (the scene
of each mesh is built again, and a state's covered points are the union of its scanned views').

Targets: predicted set size within +25 % of the proved optimum (mean over states).

    python benchmarks/cover_labels.py --manifest manifests/covers-scvp-32-1.0.0.json --meshes ../shared/meshes \\
        --cover-model runs/cover-gbm/cover.json [--scvp-checkpoint runs/scvp-net/covernet.pt] [--limit 40]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numba
import numpy as np
import torch

from nbvdata.core.config import SimConfig, from_dict
from nbvdata.core.views import ViewSet, look_at_rotations
from nbvdata.schema.manifest import open_verified
from nbvdata.schema.shards import Shard, view_state
from nbvdata.simulation.episode import scene_rng
from nbvdata.simulation.oracle import popcount
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.sources import part_sources
from nbvtrain.planners import CoverModelPlanner, Observation, SCVPNetPlanner, robot_radius


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--manifest", type=Path, required=True)
    parser.add_argument("--meshes", type=Path, required=True)
    parser.add_argument("--cover-model", type=Path, required=True)
    parser.add_argument("--scvp-checkpoint", type=Path)
    parser.add_argument("--limit", type=int, default=40, help="validation meshes (the first in the manifest's order)")
    args = parser.parse_args()
    numba.set_num_threads(1)
    torch.set_num_threads(1)
    published = open_verified(args.manifest, None)
    (sources, _) = part_sources(args.manifest, "val", args.meshes)
    sources = sources[:args.limit]
    paths = {entry["path"]: path for entry, path in zip(published.content["shards"], published.shard_paths)}
    by_mesh = {}
    for path in paths.values():
        with Shard(path) as shard:
            by_mesh[shard["mesh_id"][0].decode() if len(shard["mesh_id"]) else ""] = path
    totals: dict[str, list] = {}
    for source in sources:
        path = by_mesh.get(source.mesh_id)
        if path is None:
            continue
        with Shard(path) as shard:
            config = from_dict(SimConfig, shard.info.config or {})
            positions = shard["view_positions"]
            taken = view_state(shard["run"], shard["step"], shard["last_view"], len(positions))
            grids, covers = shard.grids(), shard["cover"].astype(bool)
        views = ViewSet(positions, look_at_rotations(positions))
        scene = Scene.build(source.load(config.mesh), config, scene_rng(config.episode.seed, source.mesh_id), 1)
        oracle = scene.oracle
        radius = robot_radius(config)
        planners = {"cover": CoverModelPlanner(args.cover_model, views, config, radius)}
        if args.scvp_checkpoint:
            planners["scvp-net"] = SCVPNetPlanner(args.scvp_checkpoint, views, radius)
        for i in range(len(grids)):
            scanned = np.flatnonzero(taken[i])
            covered = np.bitwise_or.reduce(oracle.visible[scanned], axis=0)
            remaining = oracle.observable & ~covered
            optimal = set(np.flatnonzero(covers[i]).tolist())
            if not optimal:
                continue
            observation = Observation(grids[i], tuple(views[v] for v in scanned))
            for name, planner in planners.items():
                planned = set(planner.planned_set(observation))
                union = np.bitwise_or.reduce(oracle.visible[sorted(planned)], axis=0)
                left = popcount(remaining & ~union)
                totals.setdefault(name, []).append((len(planned), len(optimal), len(planned & optimal), left == 0,
                                                    1 - left / max(popcount(remaining), 1)))
    print(f"{args.manifest.name}: validation states of {len(sources)} meshes")
    print(f"{'model':10s} {'states':>6s} {'size':>6s} {'optimum':>8s} {'ratio':>6s} {'precision':>9s} {'recall':>7s} "
          f"{'covers':>7s} {'rest reached':>12s}")
    for name, rows in totals.items():
        size, optimum, hits, cover, reached = (np.array(column, dtype=np.float64) for column in zip(*rows))
        print(f"{name:10s} {len(rows):6d} {size.mean():6.2f} {optimum.mean():8.2f} {size.mean() / optimum.mean():6.2f} "
              f"{np.mean(hits / size):9.3f} {np.mean(hits / optimum):7.3f} {100 * cover.mean():6.1f}% "
              f"{100 * reached.mean():11.1f}%")


if __name__ == "__main__":
    main()
