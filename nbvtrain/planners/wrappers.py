"""Planners around another planner: ``SnappedPlanner`` takes its answers to the run's candidate views
(what a protocol of fixed, reachable views asks), ``TravelPlanner`` weighs the path to each view
against its score (``--travel-weight``).
"""

from __future__ import annotations

import numpy as np

from nbvdata.core.config import ConfigError
from nbvdata.core.paths import path_length
from nbvdata.core.views import Pose, ViewSet, scanned_views
from nbvdata.simulation.episode import Reconstruction
from nbvtrain.planners.base import Observation, Planner


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
    object's bounding sphere (``nbvdata.core.paths.path_length``; radius ``radius``: what the robot
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
