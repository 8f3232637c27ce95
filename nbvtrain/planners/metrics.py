"""The field's hand-crafted volumetric metrics as planners (``MetricPlanner``): ``occlusion-aware``,
``unobserved-voxel``, ``rear-side-voxel``, ``rear-side-entropy``, ``proximity-count``,
``average-entropy``, ``area-factor`` and ``proximity-shadow``, each the unscanned candidate view
with the highest value of its column of ``nbvdata.simulation.viewfeatures`` (``METRICS``), over every
candidate view; and ``expected-surface`` (``SurfacePlanner``), the same over the surface a learned
prior expects each view to newly see (``nbvtrain.ranking.surfaceprior``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nbvdata.core.config import SimConfig
from nbvdata.core.views import Pose, ViewSet, scanned_views
from nbvdata.simulation.episode import Reconstruction
from nbvtrain.planners.base import Observation, Planner, register_planner


class MetricPlanner(Planner):
    """A hand-crafted volumetric metric over every candidate view (``nbvdata.simulation.viewfeatures.METRICS``:
    Delmerico et al. 2018's and Vasquez-Gomez et al. 2014's, from one walk of the grid over each
    view's coarse ray bundle, ``METRIC_BUNDLE`` rays): the unscanned view with the highest value (the lowest index among
    equals; each scanned pose marks its nearest view). No overlap rule, as in their planners."""

    def __init__(self, name: str, views: ViewSet, config: SimConfig, column: str | None = None):
        from nbvdata.simulation.viewfeatures import FEATURES, METRICS

        self.name, self.views, self.config = name, views, config
        self.column = FEATURES.index(column or METRICS[name])

    def values(self, observation: Observation) -> np.ndarray:
        """(V,) the metric of every candidate view at the observation."""
        from nbvdata.simulation.viewfeatures import METRIC_BUNDLE, view_features
        from nbvtrain.ranking.rankdata import bundle_for

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
                     "candidate view, from its coarse ray bundle (`nbvdata.simulation.viewfeatures`)", default=False)(
        lambda context, _metric=_metric: [MetricPlanner(_metric, context.views, context.config)])


class SurfacePlanner(MetricPlanner):
    """``expected-surface``: the unscanned view whose rays can expect to newly see the most surface,
    by a surface prior's P(surface) of the unknown voxels each ray passes before its first occupied
    one (``nbvdata.simulation.viewfeatures``'s ``expected_surface``; the prior: ``--surface-prior``)."""

    def __init__(self, prior: Path, views: ViewSet, config: SimConfig):
        from nbvtrain.ranking.surfaceprior import load_surface_prior

        super().__init__("expected-surface", views, config, "expected_surface")
        self.prior = load_surface_prior(prior)
        self.prior.check_scene(config, "--surface-prior")

    def values(self, observation: Observation) -> np.ndarray:
        from nbvdata.simulation.viewfeatures import METRIC_BUNDLE, shadow_weights, view_features
        from nbvtrain.ranking.rankdata import bundle_for

        bundle = bundle_for(self.views, self.config, METRIC_BUNDLE)
        shadow = shadow_weights(observation.probabilities, observation.positions, bundle)
        surface = self.prior.probabilities(observation.probabilities, shadow)
        features = view_features(observation.probabilities, observation.positions, bundle, surface, shadow)
        return features[:, self.column].astype(np.float64)


register_planner("expected-surface", ("grid", "poses"), "the unscanned candidate view whose rays can expect to newly "
                 "see the most surface: a learned surface prior's P(surface) of the unknown voxels each passes before "
                 "its first occupied one; over every candidate view (`--surface-prior`, a surface.json of nbvtrain fit "
                 "--model surface-gbm)", default=False)(
    lambda context: [SurfacePlanner(context.checkpoint("surface"), context.views, context.config)])
