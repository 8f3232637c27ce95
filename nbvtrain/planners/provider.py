"""Trained models as ``nbvdata.simulation.policy.Policy``: the moves ``nbvdata generate --policy`` follows.

The moves are exactly those of ``nbvtrain evaluate``'s planner for the checkpoint
(``nbvtrain.planners.LearnedPlanner``): the regression network's direction at the view sphere's
radius, looking at the centre (a continuous pose, not snapped to a candidate view), the
classification network's class view, or the score network's best unscanned candidate view.

``CheckpointPolicy`` is the ``checkpoint`` provider of the ``nbvdata.policies`` entry-point group
(pyproject.toml): nbvdata finds it there, by name, and imports it only when ``--policy`` is given.
``RankerPolicy`` is the ``viewrank`` provider (``--policy viewrank.json --policy-provider
viewrank``): a ranker of per-view features (``nbvtrain.ranking.viewrank``) moves as the ``viewrank``
planner does, to the unscanned candidate view it ranks first - the learner's own states, for
DAgger rounds of a ranker.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from nbvdata.core.config import SimConfig
from nbvdata.core.views import Pose, view_sphere
from nbvdata.simulation.policy import PolicyError
from nbvtrain.networks.checkpoint import load_checkpoint
from nbvtrain.networks.models import architecture
from nbvtrain.planners.base import Observation
from nbvtrain.planners.networks import LearnedPlanner


class CheckpointPolicy:
    """``next_move(probabilities, poses) -> view index | Pose`` of the network in ``checkpoint``.

    ``config``: the run's settings (view sphere and candidate views); ``threads`` > 0 limits
    torch to that many threads.
    """

    def __init__(self, checkpoint: str | Path, config: SimConfig, threads: int = 0):
        if threads:
            torch.set_num_threads(threads)
        from nbvtrain.ranking.viewrank import is_ranker_file

        if is_ranker_file(checkpoint):
            raise PolicyError(f"--policy {checkpoint}: a ranker of per-view features, not a network's checkpoint: add "
                              "--policy-provider viewrank")
        state = load_checkpoint(checkpoint)  # CheckpointError: one line naming the file and the fix
        if architecture(state["model"]).inputs == "points":
            raise PolicyError(f"--policy {checkpoint}: {state['model']} reads point clouds, which a policy's runs do "
                              "not hand it yet: use a grid network's checkpoint (nbvtrain evaluate runs it in closed "
                              "loop)")
        self.planner = LearnedPlanner(checkpoint, config.views.radius, architecture(state["model"]).task,
                                      view_sphere(config.views), config=config)
        self.name = f"{state['model']} epoch {state['epoch']}"

    def start(self, seed: np.random.SeedSequence) -> None:
        self.planner.start(seed)

    def next_move(self, probabilities: np.ndarray, poses: tuple[Pose, ...]) -> int | Pose:
        """A score network's candidate view index (so the shards record it as the view taken and
        the view state stays known), or the regression or classification network's pose."""
        observation = Observation(probabilities, tuple(poses))
        if self.planner.predictor.model.task == "scores":
            return self.planner.next_view(observation)
        return self.planner.next_pose(observation)


class RankerPolicy:
    """``next_move(probabilities, poses) -> view index``: the unscanned candidate view a ranker
    (``viewrank.json`` or ``.pt``) ranks first, each scanned pose marking its nearest view
    (``nbvtrain.planners.RankerPlanner``). ``config``: the run's settings (the candidate views; a
    ranker of another grid is refused); ``threads`` > 0 limits numba and torch to that many threads."""

    def __init__(self, model: str | Path, config: SimConfig, threads: int = 0):
        from nbvtrain.networks.checkpoint import CheckpointError
        from nbvtrain.planners.ranker import RankerPlanner

        if threads:
            import numba

            numba.set_num_threads(threads)
            torch.set_num_threads(threads)
        try:
            self.planner = RankerPlanner(model, view_sphere(config.views), config)
        except CheckpointError as error:
            raise PolicyError(f"--policy {error}") from None
        self.name = self.planner.ranker.kind

    def start(self, seed: np.random.SeedSequence) -> None:
        """Nothing to seed: the ranker's choice is a function of the state."""

    def next_move(self, probabilities: np.ndarray, poses: tuple[Pose, ...]) -> int:
        return self.planner.next_view(Observation(probabilities, tuple(poses)))
