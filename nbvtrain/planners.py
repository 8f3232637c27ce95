"""Next-best-view planners behind one interface: ``planner.next_pose(observation) -> Pose``,
and their registry: ``PLANNERS`` maps each name ``nbvtrain evaluate --planners`` takes to a
``PlannerKind`` (what it reads, its options, what it chooses, how it is built); a planner joins it
with ``@register_planner``, and ``build_planners``, the CLI's check, the docs' table
(``planner_table``) and the tests are made from it.

A planner decides from what a real robot has, an ``Observation``: the occupancy grid and the
poses scanned so far. Only the oracle is privileged: it is also handed the simulation's
``Reconstruction`` (which knows the mesh) and is an upper bound, not a method.

- ``scores``: a trained candidate-score network (``nbvscore-*``); the candidate view with the
  highest score among those not scanned yet (a scanned pose marks its nearest candidate view,
  ``nbvdata.views.scanned_views``), so it never repeats a view. Several checkpoints are an
  ensemble: the mean of their scores, each standardised over the unscanned views
  (``nbvtrain.scores.standardise``), so every network has one vote whatever the scale of its
  scores (their losses fix them only up to a shift, and their sharpness grows with training).
- ``regression``: a trained NBV-net; its output direction, taken as it is (not snapped to a
  candidate), at the view sphere's radius, looking at the centre (``nbvtrain.predict``).
- ``classification``: NBV-Net's 14 fixed views; the chosen class's position.
- With ``spread`` W (``nbvtrain evaluate --spread W``), regression and classification take the
  unscanned candidate view v with the highest cos(answer, v) - W cos(v, its nearest scan)
  (``nbvdata.views.spread_view``): their answer spread away from what was scanned; it never
  repeats a view. W = 0 is the unscanned view nearest the answer.
- With ``no_stall`` (``nbvtrain evaluate --no-stall``), regression and classification do not
  repeat a scan: when the candidate view nearest to their pose is one a scan already marked,
  classification takes its next most likely class that repeats nothing, regression (and
  classification when every class repeats) the candidate view nearest to its output that was
  not scanned. Off (the default) is the paper's behaviour.
- ``infogain``: Kriegel et al. 2012, exhaustive over 20 views spread like the candidate views
  (``views.layout``: the upper hemisphere by default, as the authors' data): every sensor
  ray walks the grid from the sensor (OctoMap's DDA, as the integration) until the first
  occupied voxel (p > 0.5) or the sensor's far range, adding the entropy H(p) of every unknown
  voxel it passes inside the object's box. A view must pass the overlap constraint, estimated
  from the grid: of its rays that reach the box and meet a non-free voxel there, the share whose
  first such voxel is known occupied (surface seen before) must be >= ``min_overlap``; when no
  view passes, the most informative view is taken (as the oracle does).
- ``oracle``: the exhaustive ground truth of ``nbvdata.oracle`` over every candidate view; once no
  view adds anything at the scene's match distance, ``farthest``'s view.
- ``viewrank``: a ranker of per-view features (``nbvtrain.viewrank``, ``RankerPlanner``) on any view set.
- ``occlusion-aware``, ``unobserved-voxel``, ``rear-side-voxel``, ``rear-side-entropy``,
  ``proximity-count``, ``average-entropy``, ``area-factor``, ``proximity-shadow``: the field's hand-crafted metrics over
  every candidate view (``nbvdata.viewfeatures.METRICS``, ``MetricPlanner``).
- ``setcover``: SCVP's one-shot plan, privileged like the oracle: at its first decision it
  solves the state's set cover (``nbvdata.setcover``, the fewest views that cover the rest) once,
  then scans the planned views in the order of the shortest tour from where the sensor is
  (``nbvdata.paths.shortest_tour``, round the object's bounding sphere: MA-SCVP's point, a
  shorter path); with the plan done (everything observable covered) it takes the view adding
  the most, as the oracle without the overlap rule. The overlap rule is no part of the plan, as
  in SCVP.
- ``random``: a seeded uniformly random candidate view.
- ``farthest``: the unscanned candidate view farthest in angle from every pose scanned so far
  (greedy farthest-point sampling of the view sphere). It reads neither the grid nor the mesh:
  what spreading the views alone covers, the baseline that shows whether a planner's grid
  reading adds anything to that.
- ``module:function`` (or ``path/to/file.py:function``): a policy on the observation of the
  reconstruction environment ``nbvdata.env`` (``PolicyPlanner``), e.g. one trained by RL.
- ``hybrid``: the score network's standardised scores plus ``weight`` times the standardised
  information gain of every unscanned candidate view (``HybridPlanner``; 0 for a view that fails
  the overlap estimate or adds nothing, as the networks' targets give a view that breaks the
  overlap rule), from an image ``stride`` times coarser than the sensor's (the same field of
  view): weight 0 is the network's choice, a large weight information gain's among the valid views.
- ``tta`` (``nbvtrain evaluate --tta``): a learned planner averages its network's answers over
  the four quarter turns about z where that is exact (``nbvtrain.predict.Predictor``).
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import logging
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from nbvdata.cloud import reduce_cloud
from nbvdata.config import ConfigError, GridConfig, SensorConfig, SimConfig
from nbvdata.episode import Reconstruction
from nbvdata.grid import ray_information
from nbvdata.paths import path_length, shortest_tour
from nbvdata.sensor import camera_rays
from nbvdata.views import (FIXED_LAYOUTS, Pose, ViewSet, farthest_view, look_at_rotations, nearest_scan_cosines,
                           scanned_views, sphere_positions, spread_view)
from nbvtrain.models import class_positions
from nbvtrain.scores import pick, standardise

if TYPE_CHECKING:
    from nbvtrain.predict import Predictor

READS = {"grid": "the grid", "poses": "the poses scanned", "points": "the points scanned",
         "seed": "a seeded generator", "scene": "the simulation (privileged: an upper bound, not a method)"}
"""What a planner may decide from (``PlannerKind.reads``), in the docs' words."""


def robot_radius(config: SimConfig) -> float:
    """The object's bounding sphere as a robot knows it (metres): ``mesh.object_size`` sqrt(3) / 2, the
    half-diagonal of the cube its largest side spans; the sphere a path round the object avoids."""
    return config.mesh.object_size * math.sqrt(3) / 2


@dataclass(frozen=True)
class Observation:
    """What a robot knows at a state.

    probabilities : (n, n, n) float32 occupancy grid, authors' encoding (0.5 = unknown)
    poses : the sensor poses scanned so far, oldest first
    points : (M, 3) float32 every point scanned so far, object frame, oldest scan first
             (``nbvdata.cloud.ScannedCloud``); None when the run keeps none
    """

    probabilities: np.ndarray
    poses: tuple[Pose, ...]
    points: np.ndarray | None = None

    @property
    def positions(self) -> np.ndarray:
        """(P, 3) float64 the sensor positions of ``poses``, object frame."""
        return np.array([pose.position for pose in self.poses], dtype=np.float64).reshape(-1, 3)


class Planner:
    """Base class. ``privileged`` planners also receive the simulation's state (the oracle);
    ``reads_points`` ones the scanned points (``Observation.points``)."""

    name = "planner"
    privileged = False
    reads_points = False

    def start(self, seed: int | np.random.SeedSequence) -> None:
        """Called before every reconstruction; ``seed`` is that reconstruction's stream for the
        planner (spawned apart from the sensor noise's)."""

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        raise NotImplementedError


class LearnedPlanner(Planner):
    """A trained checkpoint (candidate scores, regression or classification), through
    ``nbvtrain.predict``; for scores also several checkpoints, an ensemble. ``views``: the run's
    candidate views (a score network's picks and the no-stall rule are views of it); ``config``:
    the run's settings, which a checkpoint that records its training scene must match
    (``nbvtrain.trained_scene.check_scene``); ``tta``: quarter-turn test-time averaging (refused where it
    is not exact). The name says which: ``scores``, ``scores-ens2``, ``regression-tta``, ...

    ``foreign_views``: the run's candidate views are not the ones the network was trained with
    (a benchmark protocol's layout): only its grid must match the run's, and a score network
    answers with the best of its own views not scanned (each scanned pose marks its nearest), as a
    pose that ``SnappedPlanner`` then takes to the run's nearest unscanned view."""

    def __init__(self, checkpoint: str | Path | Sequence[str | Path], radius: float, expect: str,
                 views: ViewSet | None = None, no_stall: bool = False, config: SimConfig | None = None,
                 tta: bool = False, spread: float | None = None, foreign_views: bool = False):
        from nbvtrain.predict import Predictor
        from nbvtrain.trained_scene import check_scene

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
        unscanned views (``nbvtrain.scores.standardise``), and the mean standardised again: an
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


class OraclePlanner(Planner):
    """The valid candidate view with the largest exact gain (``nbvdata.oracle``); when no view
    passes the overlap constraint, the one with the largest gain; when no view adds anything (the
    observable surface all covered at the scene's match distance), ``farthest``'s view: the
    unscanned view farthest from the scans, which adds the most new points at finer thresholds
    (ObjView-Bench's 0.01 r; before, view 0 and its neighbours: short hops that add little)."""

    name = "oracle"
    privileged = True

    def __init__(self, views: ViewSet, min_overlap: float):
        self.views, self.min_overlap = views, min_overlap

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        scores = truth.scene.oracle.score(truth.covered)
        best = scores.best(self.min_overlap)
        if best is None:
            best = (int(np.argmax(scores.gains)) if (scores.new > 0).any()
                    else farthest_view(self.views.unit_positions, observation.positions))
        return self.views[best]

    def candidate_scores(self, observation: Observation, truth: Reconstruction | None = None
                         ) -> tuple[ViewSet, np.ndarray]:
        """(views, (V,) gains): the valid views' gains, -inf elsewhere (every view's when none is valid)."""
        scores = truth.scene.oracle.score(truth.covered)
        valid = (scores.overlaps >= self.min_overlap) & (scores.new > 0)
        return self.views, np.where(valid if valid.any() else scores.new > 0, scores.gains, -np.inf)


class SetCoverPlanner(Planner):
    """SCVP's plan: the set cover of the first state it sees, scanned in the shortest tour's order
    (see the module docstring); the plan is the scene's ``plan_cover`` of that state (within
    ``oracle.cover_node_limit`` branch-and-bound nodes, solved once per state and shared with
    the evaluation's floor)."""

    name = "setcover"
    privileged = True

    def __init__(self, views: ViewSet):
        self.views = views
        self.plan: list[int] | None = None

    def start(self, seed: int | np.random.SeedSequence) -> None:
        self.plan = None

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        oracle = truth.scene.oracle
        if self.plan is None:
            plan = list(truth.scene.plan_cover(truth.covered).views)
            order = shortest_tour(observation.positions[-1], self.views.positions[plan], truth.scene.bounding_radius)
            self.plan = [plan[i] for i in order]
        if self.plan:
            return self.views[self.plan.pop(0)]
        return self.views[int(np.argmax(oracle.score(truth.covered).new))]


class RandomPlanner(Planner):
    """A uniformly random candidate view, seeded per reconstruction."""

    name = "random"

    def __init__(self, views: ViewSet):
        self.views = views
        self.rng = np.random.default_rng(0)

    def start(self, seed: int | np.random.SeedSequence) -> None:
        self.rng = np.random.default_rng(seed)

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        return self.views[int(self.rng.integers(len(self.views)))]


class FarthestPlanner(Planner):
    """The unscanned candidate view farthest in angle from every scanned pose (the lowest index
    among equals); the first view with nothing scanned. Deterministic, no seed."""

    name = "farthest"

    def __init__(self, views: ViewSet):
        self.views = views

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        return self.views[farthest_view(self.views.unit_positions, observation.positions)]

    def candidate_scores(self, observation: Observation, truth: Reconstruction | None = None
                         ) -> tuple[ViewSet, np.ndarray]:
        """(views, (V,) minus the cosine to the nearest scan): farther is higher; scanned views -inf."""
        units = self.views.unit_positions
        taken = scanned_views(observation.positions, units)
        return self.views, np.where(taken, -np.inf, -nearest_scan_cosines(units, observation.positions))


class SnappedPlanner(Planner):
    """``planner`` whose answers are always one of the run's candidate views ``views``: a pose that
    is none (a regression network's direction, information gain's own views, a network trained
    on other views) becomes the unscanned candidate view nearest to it in direction (every view
    scanned: the nearest). What a protocol of fixed, reachable views asks (ObjView-Bench refuses
    any other pose). The name and everything else are the planner's."""

    def __init__(self, planner: Planner, views: ViewSet):
        self.planner, self.views = planner, views
        self.name, self.privileged, self.reads_points = planner.name, planner.privileged, planner.reads_points

    def start(self, seed: int | np.random.SeedSequence) -> None:
        self.planner.start(seed)

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        pose = self.planner.next_pose(observation, truth)
        exact = np.flatnonzero((self.views.positions == pose.position).all(axis=1))
        if len(exact):
            return self.views[int(exact[0])]
        units = self.views.unit_positions
        direction = pose.position / np.linalg.norm(pose.position)
        free = np.flatnonzero(~scanned_views(observation.positions, units))
        candidates = free if len(free) else np.arange(len(units))
        return self.views[int(candidates[np.argmax(units[candidates] @ direction)])]


class TravelPlanner(Planner):
    """A greedy planner that also weighs the path to the view: of the views its ``candidate_scores``
    allows, the one with the highest s - ``weight`` p, s its score scaled to [0, 1] over the
    allowed views (lowest 0, highest 1) and p the path to the view from the last scan round the
    object's bounding sphere (``nbvdata.paths.path_length``; radius ``radius``: what the robot
    knows, ``mesh.object_size`` sqrt(3) / 2) scaled by the longest such path among them. Weight 0 is
    the planner's own choice; a large weight the nearest allowed view. Named ``NAME-travelW``."""

    def __init__(self, planner: Planner, weight: float, radius: float):
        if not hasattr(planner, "candidate_scores"):
            raise ConfigError(f"--travel-weight: {planner.name} does not score every view (oracle, scores, infogain and "
                              "farthest do)")
        self.planner, self.weight, self.radius = planner, weight, radius
        self.name = f"{planner.name}-travel{weight:g}"
        self.privileged, self.reads_points = planner.privileged, planner.reads_points

    def start(self, seed: int | np.random.SeedSequence) -> None:
        self.planner.start(seed)

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        if self.weight == 0:  # exactly the planner's choice, its ties included
            return self.planner.next_pose(observation, truth)
        views, scores = self.planner.candidate_scores(observation, truth)
        allowed = np.isfinite(scores)
        if not allowed.any():
            return self.planner.next_pose(observation, truth)
        low, high = scores[allowed].min(), scores[allowed].max()
        scaled = (scores - low) / (high - low) if high > low else np.ones_like(scores)
        here = observation.positions[-1]
        paths = np.array([path_length(here, position, self.radius) if ok else 0.0
                          for position, ok in zip(views.positions, allowed)])
        longest = paths[allowed].max()
        value = np.where(allowed, scaled - self.weight * (paths / longest if longest > 0 else 0.0), -np.inf)
        return views[int(np.argmax(value))]


class PolicyPlanner(Planner):
    """A policy on the environment's observation (``nbvdata.env``), named ``module:function`` or
    ``path/to/file.py:function``: ``function(observation) -> action``.

    observation : dict, as ``nbvdata.env.ReconstructEnv`` returns it: ``grid`` (n, n, n) float32
        occupancy probabilities (0.5 = unknown), ``taken`` (V,) int8 candidate views scanned (a
        pose marks its nearest view)
    action : a candidate view index (an integer, as ``action="view"``) or a (3,) direction from
        the object centre (as ``action="pose"``; the sensor goes there on the view sphere)

    The function is called once per decision, in a fixed order, and is given no seed: a
    stochastic policy seeds itself. The module is imported with the working folder on the path.
    """

    def __init__(self, spec: str, views: ViewSet):
        try:
            import nbvdata.env  # noqa: F401  (gymnasium, the optional extra [rl])
        except ImportError as error:
            raise ConfigError(f"--planners {spec}: {error}") from None
        self.name, self.views = spec, views
        self.policy = policy_function(spec)

    def __reduce__(self):
        """Pickled as its arguments: a worker process imports the function itself."""
        return type(self), (self.name, self.views)

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        from nbvdata.env import check_view, direction_pose, observation as env_observation

        taken = scanned_views(observation.positions, self.views.unit_positions)
        action = self.policy(env_observation(observation.probabilities, taken))
        returned = f"policy {self.name} returned"
        try:
            if np.ndim(action) == 0:
                return self.views[check_view(action, len(self.views), returned)]
            return direction_pose(action, self.views, returned)[1]
        except (TypeError, ValueError) as error:
            raise ConfigError(f"{error} (a policy returns a candidate view index or a (3,) direction)") from None


def policy_function(spec: str):
    """The function ``spec`` names, ``module:function`` or ``path/to/file.py:function``;
    ConfigError (one line, naming the fix) when it cannot be imported or is not callable."""
    module_name, _, function_name = spec.rpartition(":")
    if not module_name or not function_name:
        raise ConfigError(f"--planners {spec!r}: a policy is module:function or path/to/file.py:function")
    try:
        if module_name.endswith(".py"):
            path = Path(module_name).resolve()
            if not path.is_file():
                raise ConfigError(f"--planners {spec}: no such file {module_name}")
            name = f"nbvtrain_policy_{path.stem}"
            module = sys.modules.get(name)
            if module is None or getattr(module, "__file__", None) != str(path):
                module_spec = importlib.util.spec_from_file_location(name, path)
                module = importlib.util.module_from_spec(module_spec)
                sys.modules[name] = module
                try:
                    module_spec.loader.exec_module(module)
                except BaseException:
                    del sys.modules[name]  # half loaded: not kept for a second try
                    raise
        else:
            if os.getcwd() not in sys.path:
                sys.path.insert(0, os.getcwd())
            module = importlib.import_module(module_name)
    except ConfigError:
        raise
    except Exception as error:  # ImportError, or whatever the module raises while it loads
        raise ConfigError(f"--planners {spec}: cannot import {module_name} ({type(error).__name__}: "
                          f"{' '.join(str(error).split())[:200]}); put it on PYTHONPATH or give "
                          "path/to/file.py:function") from None
    function = getattr(module, function_name, None)
    if not callable(function):
        raise ConfigError(f"--planners {spec}: {module_name} has no function {function_name}")
    return function


@dataclass(frozen=True)
class InfoGainScores:
    """Per view: information (nats), rays meeting known surface first, rays meeting unknown first,
    overlap estimate; all (V,)."""

    information: np.ndarray
    known_rays: np.ndarray
    unknown_rays: np.ndarray

    @property
    def overlaps(self) -> np.ndarray:
        met = self.known_rays + self.unknown_rays
        return np.divide(self.known_rays, met, out=np.zeros(len(met)), where=met > 0)


class InfoGainPlanner(Planner):
    """Kriegel et al. 2012 information gain over ``count`` views on the view sphere, laid out like
    the candidate views (``layout``; see the module docstring; a fixed layout such as
    ``pc-nbv-33``: its own views, whatever ``count``).

    The object's box is the cube of side ``box`` metres around the centre (what the robot is told
    about the object's size, ``mesh.object_size``), not the mesh's own bounds. A voxel is unknown
    when its probability lies in [``unknown_low``, ``unknown_high``]: by default exactly 0.5,
    never observed; (0.2, 0.8) is Delmerico et al.'s band.
    """

    name = "infogain"

    def __init__(self, grid: GridConfig, sensor: SensorConfig, radius: float, box: float, min_overlap: float,
                 count: int = 20, layout: str = "hemisphere", unknown_low: float = 0.5, unknown_high: float = 0.5):
        self.grid, self.min_overlap = grid, min_overlap
        self.unknown = (np.float32(unknown_low), np.float32(unknown_high))
        if layout in FIXED_LAYOUTS:  # a fixed layout (PC-NBV's 33 views): its own views
            count = len(FIXED_LAYOUTS[layout]())
        positions = sphere_positions(count, radius, layout)
        self.views = ViewSet(positions, look_at_rotations(positions))
        rays = camera_rays(sensor)  # (N, 3) camera frame
        directions = np.matmul(rays[None], self.views.rotations)  # (V, N, 3) world: R^T d
        self._origins = positions.astype(np.float32)
        # Each ray ends at the far range, in float32 like the scan points the grid integrates.
        self._ends = (positions[:, None] + directions * sensor.far).astype(np.float32)
        n, resolution = grid.size, grid.resolution
        centres = (np.arange(n) - n // 2 + 0.5) * resolution
        inside = np.flatnonzero(np.abs(centres) <= box / 2)
        self._box = (int(inside[0]), int(inside[-1]) + 1) if len(inside) else (0, 0)
        self._scratch = np.zeros((n, n, n), dtype=np.uint8)  # the DDA's marks, unused here
        self.scores(np.full((n, n, n), 0.5, dtype=np.float32))  # compile now, not in the first decision

    def scores(self, probabilities: np.ndarray) -> InfoGainScores:
        """Information gain and overlap counts of every view for a (n, n, n) grid."""
        probabilities = np.ascontiguousarray(probabilities, dtype=np.float32)
        information = np.zeros(self._ends.shape[:2])
        first = np.zeros(self._ends.shape[:2], dtype=np.int8)
        ray_information(self._origins, self._ends, probabilities, self.grid.resolution, -(self.grid.size // 2),
                         self._box[0], self._box[1], self.unknown[0], self.unknown[1], self._scratch,
                         information, first)
        return InfoGainScores(information.sum(axis=1), (first == 1).sum(axis=1), (first == 2).sum(axis=1))

    def best_view(self, probabilities: np.ndarray) -> int:
        """The valid view with the most information (ties: the lowest index); when no view is
        valid, the most informative one."""
        scores = self.scores(probabilities)
        valid = scores.overlaps >= self.min_overlap
        if not valid.any():
            valid[:] = True
        return int(np.argmax(np.where(valid, scores.information, -1.0)))

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        return self.views[self.best_view(observation.probabilities)]

    def candidate_scores(self, observation: Observation, truth: Reconstruction | None = None
                         ) -> tuple[ViewSet, np.ndarray]:
        """(its own views, (V,) information): the views that pass the overlap estimate (every view
        when none does)."""
        scores = self.scores(observation.probabilities)
        valid = scores.overlaps >= self.min_overlap
        return self.views, np.where(valid if valid.any() else np.ones_like(valid), scores.information, -np.inf)


class MetricPlanner(Planner):
    """A hand-crafted volumetric metric over every candidate view (``nbvdata.viewfeatures.METRICS``:
    Delmerico et al. 2018's and Vasquez-Gomez et al. 2014's, from one walk of the grid over each
    view's coarse ray bundle, ``METRIC_BUNDLE`` rays): the unscanned view with the highest value (the lowest index among
    equals; each scanned pose marks its nearest view). No overlap rule, as in their planners."""

    def __init__(self, name: str, views: ViewSet, config: SimConfig):
        from nbvdata.viewfeatures import FEATURES, METRICS

        self.name, self.views, self.config = name, views, config
        self.column = FEATURES.index(METRICS[name])

    def values(self, observation: Observation) -> np.ndarray:
        """(V,) the metric of every candidate view at the observation."""
        from nbvdata.viewfeatures import METRIC_BUNDLE, view_features
        from nbvtrain.rankdata import bundle_for

        features = view_features(observation.probabilities, observation.positions,
                                 bundle_for(self.views, self.config, METRIC_BUNDLE))
        return features[:, self.column].astype(np.float64)

    def candidate_scores(self, observation: Observation, truth: Reconstruction | None = None
                         ) -> tuple[ViewSet, np.ndarray]:
        """(views, (V,) the metric), scanned views -inf."""
        taken = scanned_views(observation.positions, self.views.unit_positions)
        return self.views, np.where(taken, -np.inf, self.values(observation))

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        views, scores = self.candidate_scores(observation)
        return views[int(np.argmax(scores)) if np.isfinite(scores).any() else 0]


class RankerPlanner(Planner):
    """A learned ranker of candidate views (``nbvtrain.viewrank``: ``viewrank-gbm`` or
    ``viewrank-mlp``; ``model`` its file), on any view set: the unscanned view with the highest score
    of its per-view features (the lowest index among equals; each scanned pose marks its nearest
    view). Named ``viewrank``."""

    name = "viewrank"

    def __init__(self, model: str | Path, views: ViewSet, config: SimConfig, name: str = "viewrank"):
        from nbvtrain.viewrank import load_ranker

        self.name = name
        self.model, self.views, self.config = model, views, config
        self.ranker = load_ranker(model)
        self.ranker.check_scene(config, str(model))

    def __reduce__(self):
        """Pickled as its arguments: a worker process loads the model file itself."""
        return type(self), (self.model, self.views, self.config, self.name)

    def candidate_scores(self, observation: Observation, truth: Reconstruction | None = None
                         ) -> tuple[ViewSet, np.ndarray]:
        """(views, (V,) the ranker's scores), scanned views -inf."""
        taken = scanned_views(observation.positions, self.views.unit_positions)
        scores = self.ranker.view_scores(observation.probabilities, observation.positions, self.views, self.config)
        return self.views, np.where(taken, -np.inf, scores)

    def next_view(self, observation: Observation) -> int:
        """The ranker's choice as a candidate view index."""
        _, scores = self.candidate_scores(observation)
        return int(np.argmax(scores)) if np.isfinite(scores).any() else 0

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        return self.views[self.next_view(observation)]


class CoverPlanner(Planner):
    """A learned one-shot plan (SCVP's idea): from the current state, a model predicts the set of
    candidate views that will cover what is left - every unscanned view whose probability of being
    in the state's exact cover reaches the model's threshold (``chosen``; ``cover`` takes its
    expected number of most probable views instead) - and the planner visits it in the shortest
    tour's order from where the sensor is (``nbvdata.paths.shortest_tour``, round the bounding
    sphere a robot knows, ``radius``). With the set done it predicts again from the state it has
    reached (re-activation) until the budget. A prediction in which no view reaches the threshold
    says the cover is done: the plan is then every unscanned view, the most probable first, and
    the model is not asked again (before, it was asked at every decision for one view).

    ``travel_weight`` L > 0 trades views for path: the planned set drops, one at a time, the view
    whose detour in the tour (d(prev, v) + d(v, next) - d(prev, next), in view-sphere radii) times L
    exceeds its probability by the most, until none does (L = 0: the set as predicted; it keeps
    one view at least). Subclasses give ``probabilities(observation) -> (V,)`` and ``threshold``."""

    threshold = 0.5

    def __init__(self, views: ViewSet, radius: float, travel_weight: float = 0.0):
        self.views, self.radius, self.travel_weight = views, radius, float(travel_weight)
        self.plan: list[int] = []

    def probabilities(self, observation: Observation) -> np.ndarray:
        raise NotImplementedError

    def start(self, seed: int | np.random.SeedSequence) -> None:
        self.plan = []

    def planned_set(self, observation: Observation) -> list[int]:
        """The views to visit next, in tour order, predicted from ``observation`` (class docstring);
        where no view reaches the threshold (the model's cover is done), every unscanned view, the most
        probable first: one prediction serves the rest of the run instead of one per decision."""
        taken = scanned_views(observation.positions, self.views.unit_positions)
        probabilities = np.where(taken, -np.inf, self.probabilities(observation))
        chosen = self.chosen(probabilities)
        if chosen is None:
            free = np.flatnonzero(np.isfinite(probabilities))
            return [int(v) for v in free[np.argsort(-probabilities[free], kind="stable")]] or [0]
        here = observation.positions[-1] if len(observation.positions) else self.views.positions[chosen[0]]
        order = [chosen[i] for i in shortest_tour(here, self.views.positions[chosen], self.radius)]
        if self.travel_weight > 0:
            order = self._pruned(here, order, probabilities)
        return order

    def chosen(self, probabilities: np.ndarray) -> list[int] | None:
        """The planned views (unordered) of (V,) probabilities, -inf for scanned views: those that
        reach the threshold; None when none does (``planned_set``)."""
        return [int(v) for v in np.flatnonzero(probabilities >= self.threshold)] or None

    def _pruned(self, here: np.ndarray, order: list[int], probabilities: np.ndarray) -> list[int]:
        scale = float(np.linalg.norm(self.views.positions[0]))
        while len(order) > 1:
            stops = [here] + [self.views.positions[v] for v in order]
            detours = []
            for k in range(1, len(stops)):
                before = path_length(stops[k - 1], stops[k], self.radius)
                after = path_length(stops[k], stops[k + 1], self.radius) if k + 1 < len(stops) else 0.0
                skip = path_length(stops[k - 1], stops[k + 1], self.radius) if k + 1 < len(stops) else 0.0
                detours.append((before + after - skip) / scale)
            value = [self.travel_weight * detour - probabilities[v] for detour, v in zip(detours, order)]
            worst = int(np.argmax(value))
            if value[worst] <= 0:
                break
            kept = order[:worst] + order[worst + 1:]
            order = [kept[i] for i in shortest_tour(here, self.views.positions[kept], self.radius)]
        return order

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        taken = scanned_views(observation.positions, self.views.unit_positions)
        self.plan = [view for view in self.plan if not taken[view]]
        if not self.plan:
            self.plan = self.planned_set(observation)
        return self.views[self.plan.pop(0)]

    def travel(self, weight: float) -> "CoverPlanner":
        """This planner with travel weight ``weight``, named ``NAME-travelW``."""
        other = self._copy()
        other.travel_weight, other.name = float(weight), f"{self.name}-travel{weight:g}"
        return other

    def _copy(self) -> "CoverPlanner":
        raise NotImplementedError


class CoverModelPlanner(CoverPlanner):
    """``cover``: the plan of a ``cover-gbm`` model (``nbvtrain.covermodel``): each view's
    probability of being in the cover from its per-view features, on any view set; the set is the
    k most probable unscanned views, k their probabilities' sum rounded (the expected cover size)."""

    def __init__(self, model: str | Path, views: ViewSet, config: SimConfig, radius: float,
                 travel_weight: float = 0.0, name: str = "cover", warn: bool = True):
        from nbvtrain.covermodel import load_cover_model

        super().__init__(views, radius, travel_weight)
        self.name, self.model, self.config = name, model, config
        self.cover = load_cover_model(model)
        self.cover.check_scene(config, str(model))
        warning = self.cover.view_set_warning(config, str(model)) if warn else None
        if warning:  # once, where the planner is built (not again in each worker)
            logging.getLogger(__name__).warning("%s", warning)

    def __reduce__(self):
        """Pickled as its arguments: a worker process loads the model file itself."""
        return type(self), (self.model, self.views, self.config, self.radius, self.travel_weight, self.name, False)

    def _copy(self) -> "CoverPlanner":
        return type(self)(self.model, self.views, self.config, self.radius, self.travel_weight, self.name, False)

    def probabilities(self, observation: Observation) -> np.ndarray:
        return self.cover.view_probabilities(observation.probabilities, observation.positions, self.views, self.config)

    def chosen(self, probabilities: np.ndarray) -> list[int]:
        """The k most probable unscanned views, k the expected cover size (``covermodel.expected_sets``)."""
        from nbvtrain.covermodel import expected_sets

        free = np.isfinite(probabilities)
        rows = np.flatnonzero(free)
        picked = expected_sets(probabilities[rows], np.array([len(rows)]))
        return sorted(int(v) for v in rows[picked])


class SCVPNetPlanner(CoverPlanner):
    """``scvp-net``: the plan of SCVP's network (``nbvtrain.covernet``): the grid in, one probability
    per view of the one view set it was trained on (views with probability >= 0.5)."""

    def __init__(self, checkpoint: str | Path, views: ViewSet, radius: float, travel_weight: float = 0.0,
                 name: str = "scvp-net"):
        from nbvtrain.covernet import THRESHOLD, load_covernet

        super().__init__(views, radius, travel_weight)
        self.name, self.checkpoint, self.threshold = name, checkpoint, THRESHOLD
        self.net = load_covernet(checkpoint)
        trained = self.net.view_positions
        if trained.shape != views.positions.shape or not np.allclose(trained, views.positions, atol=1e-6):
            layout = fixed_layout(trained)
            raise Skipped(f"{checkpoint} predicts its {len(trained)} candidate views ({layout or 'a layout of its own'}), "
                          f"this run has {len(views)} others (scvp-net plans one view set)",
                          (layout, len(trained)) if layout else None)

    def __reduce__(self):
        return type(self), (self.checkpoint, self.views, self.radius, self.travel_weight, self.name)

    def _copy(self) -> "CoverPlanner":
        return type(self)(self.checkpoint, self.views, self.radius, self.travel_weight, self.name)

    def probabilities(self, observation: Observation) -> np.ndarray:
        return self.net.probabilities(observation.probabilities)


@dataclass(frozen=True)
class PlannerKind:
    """A registered planner. ``name``: what ``--planners`` names; ``reads``: what it decides from
    (keys of ``READS``; "scene" only for a privileged planner); ``options``: the flags that change
    it; ``chooses``: what it picks, for the docs' table; ``default``: in ``nbvtrain evaluate``'s
    default list; ``build``: ``PlannerContext`` -> its planners (one, or one per option value)."""

    name: str
    reads: tuple[str, ...]
    options: tuple[str, ...]
    chooses: str
    default: bool
    build: Callable[["PlannerContext"], list[Planner]]


PLANNERS: dict[str, PlannerKind] = {}
"""Every registered planner, by name, in the order they registered (the docs' and the CLI's)."""


def register_planner(name: str, reads: Sequence[str], chooses: str, options: Sequence[str] = (),
                     default: bool = True) -> Callable:
    """Decorator: register ``build(context) -> list[Planner]`` as the planner ``name``."""
    unknown = set(reads) - set(READS)
    if unknown:
        raise ValueError(f"planner {name}: reads {sorted(unknown)}, not among {sorted(READS)}")

    def register(build: Callable[["PlannerContext"], list[Planner]]) -> Callable:
        PLANNERS[name] = PlannerKind(name, tuple(reads), tuple(options), chooses, default, build)
        return build
    return register


def default_planners() -> list[str]:
    """The names ``nbvtrain evaluate`` runs when ``--planners`` is not given."""
    return [name for name, kind in PLANNERS.items() if kind.default]


class Skipped(Exception):
    """A planner that cannot be built here: the message says why (no checkpoint for its task: and
    what to pass). ``views``: where the planner plays one view set only, its (layout, count), from
    which each command says its own fix (``fix``)."""

    def __init__(self, message: str, views: tuple[str, int] | None = None):
        super().__init__(message)
        self.views = views

    def fix(self, settings: str) -> str:
        """The message, ending in ``settings`` (the command's way to run on ``views``) where there are views."""
        return f"{self}: {settings}" if self.views is not None else str(self)


@dataclass(frozen=True)
class PlannerContext:
    """What the planners are built from: the simulation settings, the run's candidate views, the
    checkpoints by task (None: the released model) and the evaluation's options."""

    config: SimConfig
    views: ViewSet
    checkpoints: dict[str, Path | Sequence[Path] | None]
    no_stall: bool = False
    tta: bool = False
    hybrid_weights: Sequence[float] = (1.0,)
    hybrid_stride: int = 4
    spread: float | None = None
    foreign_views: bool = False

    def checkpoint(self, task: str) -> Path | Sequence[Path]:
        """The checkpoint(s) of ``task``: given, else the released one; ``Skipped`` when neither."""
        from nbvtrain.release import NoReleasedModel, released_checkpoint

        path = self.checkpoints.get(task)
        if path is not None:
            return path
        try:
            return released_checkpoint(task)
        except NoReleasedModel as reason:
            raise Skipped(str(reason)) from None

    def rankers(self) -> list[Planner]:
        """The viewrank planners: one per given model file (several: each named by its file's folder,
        ``viewrank-FOLDER`` or the folder's own name when it starts with viewrank, to compare them),
        else the released one; ``Skipped`` when neither."""
        from nbvtrain.release import NoReleasedModel, released_ranker

        given = self.checkpoints.get("ranker")
        if given is None:
            try:
                given = [released_ranker()]
            except NoReleasedModel as reason:
                raise Skipped(str(reason)) from None
        paths = [Path(path) for path in ([given] if isinstance(given, (str, Path)) else given)]
        planners = [RankerPlanner(path, self.views, self.config) for path in paths]
        if len(planners) > 1:
            for planner, path in zip(planners, paths):
                folder = path.resolve().parent.name
                planner.name = folder if folder.startswith("viewrank") else f"viewrank-{folder}"
            if len({planner.name for planner in planners}) < len(planners):
                raise ConfigError("--ranker: two model files in folders of one name; give files of distinct run folders")
        return planners

    def learned(self, task: str) -> list[Planner]:
        config = self.config
        return [LearnedPlanner(self.checkpoint(task), config.views.radius, task, self.views, self.no_stall, config,
                               self.tta, self.spread, self.foreign_views)]

    def infogain_layout(self) -> str:
        """The layout of information gain's 20 views: the candidates', but a Fibonacci half or
        whole sphere for a fixed layout of more than 40 views (Tammes-128), as reachable."""
        layout = self.config.views.layout
        if layout not in FIXED_LAYOUTS or len(FIXED_LAYOUTS[layout]()) <= 40:
            return layout
        return "hemisphere" if (self.views.positions[:, 2] >= 0).all() else "sphere"


register_planner("scores", ("grid", "poses"), "the candidate view with the highest score of a candidate-score network "
                 "(default the released one) among those not scanned yet (each scanned pose marks its nearest "
                 "candidate view): it never repeats a view; a point-cloud network (`nbvscore-pc`) reads the points "
                 "scanned instead of the grid",
                 options=("--score-checkpoint A.pt[,B.pt]: an ensemble, `scores-ens2`", "--tta"))(
    lambda context: context.learned("scores"))
register_planner("regression", ("grid",), "the network's direction as it is (not snapped to a candidate), at the view "
                 "radius, looking at the centre (default the released one; `nbvnet-4-3-scans` also reads the poses "
                 "scanned)",
                 options=("--checkpoint", "--no-stall: `regression-nostall`", "--spread W: `regression-spreadW`",
                          "--tta"))(lambda context: context.learned("regression"))
register_planner("classification", ("grid",), "the NBV-Net class view (the authors' 14 spiral points; none is "
                 "released)", options=("--class-checkpoint", "--no-stall", "--spread W", "--tta"))(
    lambda context: context.learned("classification"))
register_planner("infogain", ("grid",), "Kriegel et al. 2012 over 20 views laid out like the candidates: the view whose "
                 "rays pass the most entropy of unknown voxels in the object's box before the first occupied voxel "
                 "(`nbvdata.grid.ray_information`), among those whose estimated overlap passes the rule")(
    lambda context: [InfoGainPlanner(context.config.scene_grid, context.config.sensor, context.config.views.radius,
                                     context.config.mesh.object_size, context.config.oracle.min_overlap,
                                     layout=context.infogain_layout())])
register_planner("oracle", ("scene",), "the exhaustive ground truth over all candidate views (when no view is valid, "
                 "the most informative one; when no view adds anything, the unscanned view farthest from the scans)")(
    lambda context: [OraclePlanner(context.views, context.config.oracle.min_overlap)])
register_planner("setcover", ("scene",), "SCVP's one-shot plan: the set cover of its first state (docs/setcover.md), "
                 "scanned in the shortest tour's order round the object; then the view adding the most")(
    lambda context: [SetCoverPlanner(context.views)])
register_planner("random", ("seed",), "a uniformly random candidate view: a lower bound")(
    lambda context: [RandomPlanner(context.views)])
register_planner("farthest", ("poses",), "the unscanned candidate view farthest in angle from every scanned pose (greedy "
                 "farthest-point sampling of the view sphere): what spreading the views alone covers, without the grid")(
    lambda context: [FarthestPlanner(context.views)])
register_planner("viewrank", ("grid", "poses"), "the unscanned candidate view a ranker of per-view features scores "
                 "highest (`nbvtrain.viewrank`, default the released one): the rays of each view through the grid, its "
                 "angles to the scans, the grid's summary; any view set", options=("--ranker FILE[,FILE]: several, `viewrank-FOLDER`",))(
    lambda context: context.rankers())
for _metric, _what in (("occlusion-aware", "visibility-weighted entropy of every voxel its rays pass (Delmerico et al. "
                                           "2018)"),
                       ("unobserved-voxel", "visibility-weighted entropy of the unknown voxels its rays pass (Delmerico "
                                            "et al. 2018)"),
                       ("rear-side-voxel", "rays whose first occupied voxel comes straight after an unknown one: the "
                                           "back of seen surface (Delmerico et al. 2018)"),
                       ("rear-side-entropy", "entropy of the unknown voxels straight in front of such rear-side "
                                             "voxels (Delmerico et al. 2018)"),
                       ("proximity-count", "unknown voxels its rays pass, weighted by nearness to occupied ones "
                                           "(Delmerico et al. 2018)"),
                       ("average-entropy", "mean entropy per voxel along its rays that meet surface (Kriegel et al. "
                                           "2012, over every view)"),
                       ("area-factor", "Vasquez-Gomez et al. 2014's area factor: occupied and occplane shares of "
                                       "its rays near 20 % and 80 %"),
                       ("proximity-shadow", "unknown voxels its rays pass, weighted by nearness behind surface hit by "
                                            "the earlier scans' rays (proximity count as rpg_ig_active_reconstruction "
                                            "implements it)")):
    register_planner(_metric, ("grid", "poses"), f"the unscanned candidate view with the most {_what}; over every "
                     "candidate view, from its coarse ray bundle (`nbvdata.viewfeatures`)", default=False)(
        lambda context, _metric=_metric: [MetricPlanner(_metric, context.views, context.config)])
register_planner("cover", ("grid", "poses"), "a learned one-shot plan on any view set: the unscanned views a "
                 "cover-gbm model (`nbvtrain.covermodel`) puts in the state's set cover, visited in the shortest "
                 "tour's order; predicted again from the state reached once done (re-activation)",
                 options=("--cover-model FILE (a cover.json of nbvtrain fit --model cover-gbm)",
                          "--travel-weight L: `cover-travelL`"), default=False)(
    lambda context: [CoverModelPlanner(context.checkpoint("cover"), context.views, context.config,
                                       robot_radius(context.config))])
register_planner("scvp-net", ("grid",), "SCVP's network (`nbvtrain.covernet`): the views whose probability of being "
                 "in the cover is >= 0.5, on the one view set it was trained on, in the shortest tour's order; "
                 "predicted again once done", options=("--scvp-checkpoint FILE (a covernet.pt of nbvtrain fit --model "
                                                        "scvp-net)", "--travel-weight L: `scvp-net-travelL`"),
                 default=False)(
    lambda context: [SCVPNetPlanner(context.checkpoint("scvp-net"), context.views, robot_radius(context.config))])
register_planner("hybrid", ("grid", "poses"), "the score network's scores plus a weight times information gain, both "
                 "standardised over the unscanned candidate views, one planner per weight (`hybrid-w1`, ...)",
                 options=("--hybrid-weight W[,W...]",), default=False)(
    lambda context: [HybridPlanner(context.checkpoint("scores"), context.config, context.views, weight, context.tta,
                                   context.hybrid_stride) for weight in context.hybrid_weights])


def fixed_layout(positions: np.ndarray) -> str | None:
    """The name of the fixed layout (``nbvdata.views.FIXED_LAYOUTS``) whose directions ``positions``
    (V, 3) are, at any radius; None for any other view set."""
    units = positions / np.linalg.norm(positions, axis=1, keepdims=True)
    for name, directions in FIXED_LAYOUTS.items():
        known = directions()
        if known.shape == units.shape and np.allclose(known, units, atol=1e-6):
            return name
    return None


def planner_table() -> list[str]:
    """The docs' table of the registered planners (docs/evaluation.md holds it verbatim)."""
    lines = ["| planner | decides from | chooses | options |", "|---|---|---|---|"]
    for kind in PLANNERS.values():
        reads = " and ".join(READS[key] for key in kind.reads)
        extra = "" if kind.default else " (not in the default list)"
        lines.append(f"| `{kind.name}` | {reads} | {kind.chooses}{extra} | {'; '.join(kind.options) or '-'} |")
    lines.append("| `module:function` | the grid and the poses scanned (the environment's observation) | a policy's "
                 "candidate view or direction (`PolicyPlanner`, e.g. trained by RL) | - |")
    return lines


def build_planners(names: list[str], config: SimConfig, views: ViewSet,
                   checkpoints: dict[str, Path | Sequence[Path] | None], no_stall: bool = False, tta: bool = False,
                   hybrid_weights: Sequence[float] = (1.0,), hybrid_stride: int = 4,
                   spread: float | None = None, foreign_views: bool = False,
                   views_fix: Callable[[str, int], str] = lambda layout, count: f"--set views.layout={layout} --set "
                                                                                 f"views.count={count}",
                   ) -> tuple[list[Planner], list[str]]:
    """The named planners (registered ones, and ``module:function`` policies), and a message for
    each one skipped for want of a checkpoint (or, for one that plays a single view set, naming the
    calling command's way to run on it: ``views_fix(layout, count)``, by default the settings).
    ConfigError for a name not registered, listing those that are.

    ``checkpoints``: task (scores, regression, classification) -> checkpoint file (scores: also
    several, an ensemble), None for the released model of that task (``nbvtrain.release``) where
    there is one; ``hybrid`` takes the scores' and gives one planner per weight of
    ``hybrid_weights``. ``tta``: quarter-turn averaging for every learned planner; ``spread``: the
    spread rule's weight for regression and classification (``LearnedPlanner``); ``foreign_views``:
    the networks were trained on other candidate views (``LearnedPlanner``)."""
    context = PlannerContext(config, views, checkpoints, no_stall, tta, tuple(hybrid_weights), hybrid_stride, spread,
                             foreign_views)
    planners, skipped = [], []
    for name in names:
        if ":" in name:
            planners.append(PolicyPlanner(name, views))
            continue
        kind = PLANNERS.get(name)
        if kind is None:
            raise ConfigError(f"unknown planner {name!r}: choose from {', '.join(PLANNERS)}, or a policy module:function")
        try:
            planners += kind.build(context)
        except Skipped as reason:
            skipped.append(f"{name}: skipped, {reason.fix(views_fix(*reason.views) if reason.views else '')}")
    return planners, skipped
