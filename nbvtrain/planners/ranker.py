"""``viewrank``: a ranker of per-view features (``nbvtrain.ranking.viewrank``, ``RankerPlanner``) on any view
set: the unscanned view it scores highest.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nbvdata.core.config import ConfigError, SimConfig
from nbvdata.core.views import Pose, ViewSet, scanned_views
from nbvdata.simulation.episode import Reconstruction
from nbvtrain.planners.base import Observation, Planner, PlannerContext, Skipped, register_planner
from nbvtrain.planners.released import NoReleasedModel, released_ranker


class RankerPlanner(Planner):
    """A learned ranker of candidate views (``nbvtrain.ranking.viewrank``: ``viewrank-gbm`` or
    ``viewrank-mlp``; ``model`` its file), on any view set: the unscanned view with the highest score
    of its per-view features (the lowest index among equals; each scanned pose marks its nearest
    view). Named ``viewrank``."""

    name = "viewrank"

    def __init__(self, model: str | Path, views: ViewSet, config: SimConfig, name: str = "viewrank"):
        from nbvtrain.ranking.viewrank import load_ranker

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


def rankers(context: PlannerContext) -> list[Planner]:
    """The viewrank planners of a context: one per given model file (several: each named by its
    file's folder, ``viewrank-FOLDER`` or the folder's own name when it starts with viewrank, to
    compare them), else the released one; ``Skipped`` when neither."""
    given = context.checkpoints.get("ranker")
    if given is None:
        try:
            given = [released_ranker()]
        except NoReleasedModel as reason:
            raise Skipped(str(reason)) from None
    paths = [Path(path) for path in ([given] if isinstance(given, (str, Path)) else given)]
    planners = [RankerPlanner(path, context.views, context.config) for path in paths]
    if len(planners) > 1:
        for planner, path in zip(planners, paths):
            folder = path.resolve().parent.name
            planner.name = folder if folder.startswith("viewrank") else f"viewrank-{folder}"
        if len({planner.name for planner in planners}) < len(planners):
            raise ConfigError("--ranker: two model files in folders of one name; give files of distinct run folders")
    return planners


register_planner("viewrank", ("grid", "poses"), "the unscanned candidate view a ranker of per-view features scores "
                 "highest (`nbvtrain.ranking.viewrank`, default the released one): the rays of each view through the grid, its "
                 "angles to the scans, the grid's summary; any view set", options=("--ranker FILE[,FILE]: several, `viewrank-FOLDER`",))(
    lambda context: rankers(context))
