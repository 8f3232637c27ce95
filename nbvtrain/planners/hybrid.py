"""``hybrid``: the score network's standardised scores plus ``weight`` times the standardised
information gain of every unscanned candidate view (``HybridPlanner``; 0 for a view that fails
the overlap estimate or adds nothing), from an image ``stride`` times coarser than the sensor's:
weight 0 is the network's choice, a large weight information gain's among the valid views.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from nbvdata.core.config import ConfigError, SimConfig
from nbvdata.core.views import ViewSet
from nbvtrain.networks.scores import standardise
from nbvtrain.planners.base import Observation, register_planner
from nbvtrain.planners.infogain import InfoGainPlanner
from nbvtrain.planners.networks import LearnedPlanner


class HybridPlanner(LearnedPlanner):
    """Candidate scores plus information gain: the unscanned candidate view with the largest
    ``view_scores`` = standardised network scores (``LearnedPlanner.view_scores``: one network or
    an ensemble) + ``weight`` x standardised information gain of every candidate view, the gain
    set to 0 for a view that is not valid while some unscanned view is (valid: an overlap estimate
    >= ``oracle.min_overlap`` and some information, as the oracle's valid views pass the rule and
    add surface; ``InfoGainPlanner``: its views are the run's candidate views here,
    its rays those of an image ``stride`` times coarser than the sensor's in each direction, with
    the same field of view). Both terms are z-scores over the unscanned views, so ``weight`` is the
    share of the spread each has at every step, whatever the networks' scale or the unknown
    volume left (information in nats shrinks as the object is covered): weight 1 weighs them
    equally, weight 0 is the network alone, a large weight information gain among the valid views
    (the network breaking its ties)."""

    def __init__(self, checkpoint: str | Path | Sequence[str | Path], config: SimConfig, views: ViewSet,
                 weight: float, tta: bool = False, stride: int = 4):
        if not (weight >= 0 and math.isfinite(weight)):
            raise ConfigError(f"--hybrid-weight {weight}: must be a number >= 0 (0 = the network alone)")
        if stride < 1:
            raise ConfigError(f"--hybrid-stride {stride}: must be >= 1 (1 = every ray of the sensor's image)")
        super().__init__(checkpoint, config.views.radius, "scores", views, config=config, tta=tta)
        self.weight, self.min_overlap = float(weight), config.oracle.min_overlap
        sensor = dataclasses.replace(config.sensor, width=-(-config.sensor.width // stride),
                                     height=-(-config.sensor.height // stride))
        self.infogain = None if weight == 0 else InfoGainPlanner(
            config.scene_grid, sensor, config.views.radius, config.mesh.object_size, self.min_overlap,
            count=len(views), layout=config.views.layout)
        if self.infogain is not None and not np.allclose(self.infogain.views.positions, views.positions, atol=1e-9):
            raise ValueError("the hybrid's information gain needs the run's candidate views (views.count, layout)")
        self.name = f"hybrid-w{weight:g}" + self.name.removeprefix("scores")
        self._arguments = (checkpoint, config, views, weight, tta, stride)  # LearnedPlanner.__reduce__

    def view_scores(self, observation: Observation, taken: np.ndarray) -> np.ndarray:
        network = super().view_scores(observation, taken)
        if self.infogain is None:
            return network
        scores, free = self.infogain.scores(observation.probabilities), ~taken
        valid = free & (scores.overlaps >= self.min_overlap) & (scores.information > 0)
        information = np.where(valid if valid.any() else free, scores.information, 0.0)
        return network + self.weight * standardise(information, free)


register_planner("hybrid", ("grid", "poses"), "the score network's scores plus a weight times information gain, both "
                 "standardised over the unscanned candidate views, one planner per weight (`hybrid-w1`, ...)",
                 options=("--hybrid-weight W[,W...]",), default=False)(
    lambda context: [HybridPlanner(context.checkpoint("scores"), context.config, context.views, weight, context.tta,
                                   context.hybrid_stride) for weight in context.hybrid_weights])
