"""Learned one-shot plans (SCVP's idea, ``CoverPlanner``): ``cover``, a ``cover-gbm`` model's set on
any view set, and ``scvp-net``, SCVP's network's on the one view set it was trained on; each
visited in the shortest tour's order and predicted again once done.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from nbvdata.core.config import SimConfig
from nbvdata.core.paths import path_length, shortest_tour
from nbvdata.core.views import FIXED_LAYOUTS, Pose, ViewSet, scanned_views
from nbvdata.simulation.episode import Reconstruction
from nbvtrain.planners.base import Observation, Planner, Skipped, register_planner, robot_radius


class CoverPlanner(Planner):
    """A learned one-shot plan (SCVP's idea): from the current state, a model predicts the set of
    candidate views that will cover what is left - every unscanned view whose probability of being
    in the state's exact cover reaches the model's threshold (``chosen``; ``cover`` takes its
    expected number of most probable views instead) - and the planner visits it in the shortest
    tour's order from where the sensor is (``nbvdata.core.paths.shortest_tour``, round the bounding
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
    """``cover``: the plan of a ``cover-gbm`` model (``nbvtrain.ranking.covermodel``): each view's
    probability of being in the cover from its per-view features, on any view set; the set is the
    k most probable unscanned views, k their probabilities' sum rounded (the expected cover size)."""

    def __init__(self, model: str | Path, views: ViewSet, config: SimConfig, radius: float,
                 travel_weight: float = 0.0, name: str = "cover", warn: bool = True):
        from nbvtrain.ranking.covermodel import load_cover_model

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
        from nbvtrain.ranking.covermodel import expected_sets

        free = np.isfinite(probabilities)
        rows = np.flatnonzero(free)
        picked = expected_sets(probabilities[rows], np.array([len(rows)]))
        return sorted(int(v) for v in rows[picked])


class SCVPNetPlanner(CoverPlanner):
    """``scvp-net``: the plan of SCVP's network (``nbvtrain.ranking.covernet``): the grid in, one probability
    per view of the one view set it was trained on (views with probability >= 0.5)."""

    def __init__(self, checkpoint: str | Path, views: ViewSet, radius: float, travel_weight: float = 0.0,
                 name: str = "scvp-net"):
        from nbvtrain.ranking.covernet import THRESHOLD, load_covernet

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


def fixed_layout(positions: np.ndarray) -> str | None:
    """The name of the fixed layout (``nbvdata.core.views.FIXED_LAYOUTS``) whose directions ``positions``
    (V, 3) are, at any radius; None for any other view set."""
    units = positions / np.linalg.norm(positions, axis=1, keepdims=True)
    for name, directions in FIXED_LAYOUTS.items():
        known = directions()
        if known.shape == units.shape and np.allclose(known, units, atol=1e-6):
            return name
    return None


register_planner("cover", ("grid", "poses"), "a learned one-shot plan on any view set: the unscanned views a "
                 "cover-gbm model (`nbvtrain.ranking.covermodel`) puts in the state's set cover, visited in the shortest "
                 "tour's order; predicted again from the state reached once done (re-activation)",
                 options=("--cover-model FILE (a cover.json of nbvtrain fit --model cover-gbm)",
                          "--travel-weight L: `cover-travelL`"), default=False)(
    lambda context: [CoverModelPlanner(context.checkpoint("cover"), context.views, context.config,
                                       robot_radius(context.config))])
register_planner("scvp-net", ("grid",), "SCVP's network (`nbvtrain.ranking.covernet`): the views whose probability of being "
                 "in the cover is >= 0.5, on the one view set it was trained on, in the shortest tour's order; "
                 "predicted again once done", options=("--scvp-checkpoint FILE (a covernet.pt of nbvtrain fit --model "
                                                        "scvp-net)", "--travel-weight L: `scvp-net-travelL`"),
                 default=False)(
    lambda context: [SCVPNetPlanner(context.checkpoint("scvp-net"), context.views, robot_radius(context.config))])
