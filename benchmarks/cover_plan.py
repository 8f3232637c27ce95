"""The learned set-cover planners: milliseconds per plan on one core.

Target (issue 57): a plan - the predicted set and its shortest tour - in <= 50 ms on one core.
Prints, for reconstruction states of a cover shard folder (any layout; its states' grids and scans),
the median milliseconds of a whole plan of ``cover`` (``--cover-model``: per-view features, the
classifier, the shortest tour from the last scan; and with travel weight 2, its pruning) and of ``scvp-net`` (``--scvp-checkpoint``: the
network's forward pass and the tour; its own layout only), beside one decision of the ranker
(``viewrank``, the released model: the same features and a model over them) in the same process,
and the mean planned set size.

    python benchmarks/cover_plan.py --shards data/covers/scvp-32-32 --cover-model runs/cover-gbm/cover.json \\
        [--scvp-checkpoint runs/scvp-net/covernet.pt] [--states 24] [--repeats 30]
"""

from __future__ import annotations

import argparse
import glob
from pathlib import Path

import numba
import numpy as np
import torch
from viewfeatures import median_ms  # benchmarks/viewfeatures.py, beside this script

from nbvdata.core.config import SimConfig, from_dict
from nbvdata.core.views import ViewSet, look_at_rotations
from nbvdata.schema.shards import Shard, view_state
from nbvtrain.planners import CoverModelPlanner, Observation, RankerPlanner, SCVPNetPlanner, robot_radius
from nbvtrain.planners.released import released_ranker


def observations(folder: Path, count: int) -> tuple[list[Observation], SimConfig, ViewSet]:
    """``count`` states spread over the shards of ``folder`` as observations, their scene and views."""
    found, config, views = [], None, None
    for path in sorted(glob.glob(str(folder / "*.h5")))[:count]:
        with Shard(path) as shard:
            config = from_dict(SimConfig, shard.info.config or {})
            positions = shard["view_positions"]
            views = ViewSet(positions, look_at_rotations(positions))
            taken = view_state(shard["run"], shard["step"], shard["last_view"], len(positions))
            grids = shard.grids()
            for i in range(0, len(grids), max(1, len(grids) // 2)):
                found.append(Observation(grids[i], tuple(views[v] for v in np.flatnonzero(taken[i]))))
    return found[:count], config, views


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--shards", type=Path, required=True)
    parser.add_argument("--cover-model", type=Path, required=True)
    parser.add_argument("--scvp-checkpoint", type=Path)
    parser.add_argument("--states", type=int, default=24)
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    numba.set_num_threads(1)
    torch.set_num_threads(1)
    items, config, views = observations(args.shards, args.states)
    radius = robot_radius(config)
    planners = {"viewrank (one decision, baseline)": RankerPlanner(released_ranker(), views, config),
                "cover (a whole plan)": CoverModelPlanner(args.cover_model, views, config, radius),
                "cover-travel2 (a whole plan)": CoverModelPlanner(args.cover_model, views, config, radius, 2.0)}
    if args.scvp_checkpoint:
        planners["scvp-net (a whole plan)"] = SCVPNetPlanner(args.scvp_checkpoint, views, radius)
        planners["scvp-net-travel2 (a whole plan)"] = SCVPNetPlanner(args.scvp_checkpoint, views, radius, 2.0)
    print(f"{len(items)} states of {args.shards} ({len(views)} views), one core, median of {args.repeats}")
    base = None
    for name, planner in planners.items():
        call = planner.next_pose if isinstance(planner, RankerPlanner) else planner.planned_set
        ms = median_ms(call, items, args.repeats)
        base = base or ms
        size = "" if isinstance(planner, RankerPlanner) else \
            f", {np.mean([len(planner.planned_set(item)) for item in items]):.1f} views planned"
        print(f"{name:36s} {ms:7.1f} ms  ({ms / base:.2f}x viewrank){size}")


if __name__ == "__main__":
    main()
