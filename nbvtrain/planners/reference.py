"""The reference planners, what a learned one is measured against: ``oracle``, the exhaustive
ground truth of ``nbvdata.simulation.oracle`` over every candidate view (privileged: it is handed the
simulation's ``Reconstruction``, an upper bound, not a method; once no view adds anything,
``farthest``'s view); ``setcover``, SCVP's one-shot plan, privileged too: at its first decision the
state's set cover (``nbvdata.simulation.setcover``, the fewest views that cover the rest) scanned in the
shortest tour's order from where the sensor is (``nbvdata.core.paths.shortest_tour``, round the
object's bounding sphere), then the view adding the most; ``random``, a seeded uniformly random
candidate view; ``farthest``, the unscanned candidate view farthest in angle from every pose
scanned so far (greedy farthest-point sampling of the view sphere): it reads neither the grid nor
the mesh, the baseline that shows whether a planner's grid reading adds anything.
"""

from __future__ import annotations

import numpy as np

from nbvdata.core.paths import shortest_tour
from nbvdata.core.views import Pose, ViewSet, farthest_view, nearest_scan_cosines, scanned_views
from nbvdata.simulation.episode import Reconstruction
from nbvtrain.planners.base import Observation, Planner, register_planner


class OraclePlanner(Planner):
    """The valid candidate view with the largest exact gain (``nbvdata.simulation.oracle``); when no view
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
