"""The trained networks as planners (``LearnedPlanner``): ``scores``, a candidate-score network
(``nbvscore-*``), the candidate view with the highest score among those not scanned yet (a scanned
pose marks its nearest candidate view, ``nbvdata.core.views.scanned_views``), so it never repeats a
view; several checkpoints are an ensemble, the mean of their scores, each standardised over the
unscanned views (``nbvtrain.networks.scores.standardise``). ``regression``, an NBV-net: its output
direction as it is (not snapped to a candidate), at the view sphere's radius, looking at the
centre (``nbvtrain.networks.predict``). ``classification``: NBV-Net's 14 fixed views. With ``spread`` W,
regression and classification take the unscanned candidate view v with the highest cos(answer,
v) - W cos(v, its nearest scan) (``nbvdata.core.views.spread_view``); with ``no_stall`` they do not
repeat a scan (the next most likely class, or the unscanned candidate nearest to the answer).
``tta``: the network's answers averaged over the four quarter turns about z where that is exact.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from nbvdata.core.cloud import reduce_cloud
from nbvdata.core.config import ConfigError, SimConfig
from nbvdata.core.views import Pose, ViewSet, look_at_rotations, scanned_views, spread_view
from nbvdata.simulation.episode import Reconstruction
from nbvtrain.networks.models import class_positions
from nbvtrain.networks.scores import pick, standardise
from nbvtrain.planners.base import Observation, Planner, PlannerContext, register_planner

if TYPE_CHECKING:
    from nbvtrain.networks.predict import Predictor


class LearnedPlanner(Planner):
    """A trained checkpoint (candidate scores, regression or classification), through
    ``nbvtrain.networks.predict``; for scores also several checkpoints, an ensemble. ``views``: the run's
    candidate views (a score network's picks and the no-stall rule are views of it); ``config``:
    the run's settings, which a checkpoint that records its training scene must match
    (``nbvtrain.networks.trained_scene.check_scene``); ``tta``: quarter-turn test-time averaging (refused where it
    is not exact). The name says which: ``scores``, ``scores-ens2``, ``regression-tta``, ...

    ``foreign_views``: the run's candidate views are not the ones the network was trained with
    (a benchmark protocol's layout): only its grid must match the run's, and a score network
    answers with the best of its own views not scanned (each scanned pose marks its nearest), as a
    pose that ``SnappedPlanner`` then takes to the run's nearest unscanned view."""

    def __init__(self, checkpoint: str | Path | Sequence[str | Path], radius: float, expect: str,
                 views: ViewSet | None = None, no_stall: bool = False, config: SimConfig | None = None,
                 tta: bool = False, spread: float | None = None, foreign_views: bool = False):
        from nbvtrain.networks.predict import Predictor
        from nbvtrain.networks.trained_scene import check_scene

        paths = [Path(checkpoint)] if isinstance(checkpoint, (str, Path)) else [Path(path) for path in checkpoint]
        if not paths:
            raise ValueError("no checkpoint given")
        if len(paths) > 1 and expect != "scores":
            raise ConfigError(f"{len(paths)} {expect} checkpoints: only score networks make an ensemble; pass one")
        self.predictors = []
        for path in paths:
            predictor = Predictor(path, radius=radius, tta=tta)
            task = predictor.model.task
            if task != expect:
                flags = {"classification": "--class-checkpoint", "scores": "--score-checkpoint"}
                raise ConfigError(f"{path}: a {task} network ({predictor.name}); pass it with "
                                  f"{flags.get(task, '--checkpoint')}")
            if config is not None:
                check_scene(predictor.scene, _trained_views(predictor.scene, config) if foreign_views else config, path)
            if views is None and (task == "scores" or no_stall or spread is not None):
                raise ValueError("a score network, the no-stall and the spread rule need the run's candidate views")
            if task == "scores" and not foreign_views and not np.allclose(views.unit_positions, predictor.view_units,
                                                                          atol=1e-9):
                raise ConfigError(f"{path}: scores {len(predictor.view_units)} candidate views other than this run's "
                                  f"{len(views)}: run with the settings it was trained with (--config/--set views.*)")
            self.predictors.append(predictor)
        self.predictor = self.predictors[0]
        self.reads_points = self.predictor.inputs == "points"
        if any((predictor.inputs == "points") != self.reads_points for predictor in self.predictors):
            raise ConfigError("an ensemble of grid and point networks: pass networks that read the same input")
        self.foreign_views = foreign_views
        self.views, self.no_stall = views, no_stall and expect != "scores"
        self.spread = spread if expect != "scores" else None
        self.name = (expect + ("-nostall" if self.no_stall else "") + (f"-ens{len(paths)}" if len(paths) > 1 else "")
                     + (f"-spread{self.spread:g}" if self.spread is not None else "") + ("-tta" if tta else ""))
        self._arguments = (checkpoint, radius, expect, views, no_stall, config, tta, spread, foreign_views)

    @property
    def checkpoints(self) -> list[str]:
        """The checkpoint files, one per network."""
        return [str(predictor.path) for predictor in self.predictors]

    def __reduce__(self):
        """Pickled as its arguments: a worker process loads the checkpoint itself (the network's
        oneDNN weights cannot be pickled)."""
        return type(self), self._arguments

    def scanned(self, observation: Observation) -> np.ndarray:
        """(V,) bool: the run's candidate views the observation's poses marked (each its nearest)."""
        return scanned_views(observation.positions, self.views.unit_positions)

    def view_scores(self, observation: Observation, taken: np.ndarray) -> np.ndarray:
        """(V,) the mean of the score networks' scores for the observation's (n, n, n) grid (a point
        network: its scanned points) and (V,) bool scanned views, each standardised over the
        unscanned views (``nbvtrain.networks.scores.standardise``), and the mean standardised again: an
        increasing map of the scores for one network."""
        if self.reads_points and observation.points is None:
            raise ValueError(f"{self.predictor.name} reads the scanned points: the run must keep them")
        free = ~taken
        members = [standardise(predictor.raw(self._inputs(predictor, observation), taken)[0], free)
                   for predictor in self.predictors]
        return standardise(np.mean(members, axis=0), free)

    def _inputs(self, predictor: Predictor, observation: Observation) -> np.ndarray:
        """What ``predictor`` reads of the observation: the (n, n, n) grid, or the scanned points
        reduced to its cloud size exactly as the generator stores them ((N, 3); zeros while the
        scans have hit nothing, a state the generator labels too)."""
        if not self.reads_points:
            return observation.probabilities
        return reduce_cloud(observation.points, predictor.points)[0]

    def candidate_scores(self, observation: Observation, truth: Reconstruction | None = None
                         ) -> tuple[ViewSet, np.ndarray]:
        """A score network's (views, (V,) standardised scores), scanned views -inf (its own views
        with ``foreign_views``, placed at the run's radius)."""
        if self.predictor.model.task != "scores":
            raise ValueError(f"{self.name}: only a score network scores every candidate view")
        if self.foreign_views:
            units = self.predictor.view_units
            positions = units * self.predictor.radius
            views = ViewSet(positions, look_at_rotations(positions))
        else:
            views, units = self.views, self.views.unit_positions
        taken = scanned_views(observation.positions, units)
        return views, np.where(taken, -np.inf, self.view_scores(observation, taken))

    def next_view(self, observation: Observation) -> int:
        """A score network's choice as a candidate view index (``next_pose`` is its pose); a point
        network reads the scanned points, reduced as the generator reduces them."""
        taken = self.scanned(observation)
        return int(pick(self.view_scores(observation, taken)[None], taken[None])[0])

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        task = self.predictor.model.task
        if task == "scores" and self.foreign_views:  # the best of its own views, as a pose to snap
            units = self.predictor.view_units
            taken = scanned_views(observation.positions, units)
            best = int(pick(self.view_scores(observation, taken)[None], taken[None])[0])
            return Pose.look_at(units[best] * self.predictor.radius)
        if task == "scores":
            return self.views[self.next_view(observation)]
        (prediction,) = self.predictor.predict(observation.probabilities, scans=observation.positions)
        if self.spread is not None:
            return self.views[spread_view(self.views.unit_positions, observation.positions, prediction.direction,
                                          self.spread)]
        if not self.no_stall:
            return prediction.pose
        units, taken = self.views.unit_positions, self.scanned(observation)
        if not taken[int(np.argmax(units @ prediction.direction))]:
            return prediction.pose
        if task == "classification":
            classes = class_positions()
            for index in np.argsort(-self.predictor.raw(observation.probabilities)[0], kind="stable"):
                if not taken[int(np.argmax(units @ classes[index]))]:
                    return Pose.look_at(classes[index] * self.predictor.radius)
        # regression, or every class repeats: the unscanned candidate nearest to the answer (a class
        # view's direction is the prediction's)
        free = np.flatnonzero(~taken)
        if not len(free):
            return prediction.pose
        return self.views[int(free[np.argmax(units[free] @ prediction.direction)])]


def _trained_views(recorded: dict | None, config: SimConfig) -> SimConfig:
    """``config`` with the candidate views a checkpoint's scene records (``recorded``), so that
    ``check_scene`` compares the grid only."""
    if not recorded or recorded.get("mixed"):
        return config
    views = {"count": recorded.get("views_count"), "radius": recorded.get("views_radius"),
             "layout": recorded.get("views_layout")}
    return dataclasses.replace(config, views=dataclasses.replace(
        config.views, reach="whole", **{key: value for key, value in views.items() if value is not None}))


def learned(context: PlannerContext, task: str) -> list[Planner]:
    """The network planner of ``task`` (scores, regression, classification) of a context: its
    checkpoint, else the released one."""
    config = context.config
    return [LearnedPlanner(context.checkpoint(task), config.views.radius, task, context.views, context.no_stall,
                           config, context.tta, context.spread, context.foreign_views)]


register_planner("scores", ("grid", "poses"), "the candidate view with the highest score of a candidate-score network "
                 "(default the released one) among those not scanned yet (each scanned pose marks its nearest "
                 "candidate view): it never repeats a view; a point-cloud network (`nbvscore-pc`) reads the points "
                 "scanned instead of the grid",
                 options=("--score-checkpoint A.pt[,B.pt]: an ensemble, `scores-ens2`", "--tta"))(
    lambda context: learned(context, "scores"))
register_planner("regression", ("grid",), "the network's direction as it is (not snapped to a candidate), at the view "
                 "radius, looking at the centre (default the released one; `nbvnet-4-3-scans` also reads the poses "
                 "scanned)",
                 options=("--checkpoint", "--no-stall: `regression-nostall`", "--spread W: `regression-spreadW`",
                          "--tta"))(lambda context: learned(context, "regression"))
register_planner("classification", ("grid",), "the NBV-Net class view (the authors' 14 spiral points; none is "
                 "released)", options=("--class-checkpoint", "--no-stall", "--spread W", "--tta"))(
    lambda context: learned(context, "classification"))
