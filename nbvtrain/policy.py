"""A trained checkpoint as an ``nbvdata.policy.Policy``: the moves ``nbvdata generate --policy`` follows.

The moves are exactly those of ``nbvtrain evaluate``'s planner for the checkpoint
(``nbvtrain.planners.LearnedPlanner``): the regression network's direction at the view sphere's
radius, looking at the centre (a continuous pose, not snapped to a candidate view), or the
classification network's class view. nbvdata imports this module only when ``--policy`` is given.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from nbvdata.views import Pose
from nbvtrain.checkpoint import load_checkpoint
from nbvtrain.models import architecture
from nbvtrain.planners import LearnedPlanner, Observation


class CheckpointPolicy:
    """``next_move(probabilities, poses) -> Pose`` of the network in ``checkpoint``.

    ``radius``: the view sphere's, in metres; ``threads`` > 0 limits torch to that many threads.
    """

    def __init__(self, checkpoint: str | Path, radius: float, threads: int = 0):
        if threads:
            torch.set_num_threads(threads)
        state = load_checkpoint(checkpoint)  # CheckpointError: one line naming the file and the fix
        self.planner = LearnedPlanner(checkpoint, radius, architecture(state["model"]).task)
        self.name = f"{state['model']} epoch {state['epoch']}"

    def start(self, seed: np.random.SeedSequence) -> None:
        self.planner.start(seed)

    def next_move(self, probabilities: np.ndarray, poses: tuple[Pose, ...]) -> Pose:
        return self.planner.next_pose(Observation(probabilities, tuple(poses)))
