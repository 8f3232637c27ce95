"""``infogain``, the paper's baseline: Kriegel et al. 2012, exhaustive over 20 views spread like
the candidate views (``views.layout``: the upper hemisphere by default, as the authors' data):
every sensor ray walks the grid from the sensor (OctoMap's DDA, as the integration) until the
first occupied voxel (p > 0.5) or the sensor's far range, adding the entropy H(p) of every unknown
voxel it passes inside the object's box. A view must pass the overlap constraint, estimated from
the grid: of its rays that reach the box and meet a non-free voxel there, the share whose first
such voxel is known occupied (surface seen before) must be >= ``min_overlap``; when no view
passes, the most informative view is taken (as the oracle does).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nbvdata.core.config import GridConfig, SensorConfig
from nbvdata.core.views import FIXED_LAYOUTS, Pose, ViewSet, look_at_rotations, sphere_positions
from nbvdata.simulation.episode import Reconstruction
from nbvdata.simulation.grid import ray_information
from nbvdata.simulation.sensor import camera_rays
from nbvtrain.planners.base import Observation, Planner, PlannerContext, register_planner


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


def infogain_layout(context: PlannerContext) -> str:
    """The layout of information gain's 20 views: the candidates', but a Fibonacci half or whole
    sphere for a fixed layout of more than 40 views (Tammes-128), as reachable."""
    layout = context.config.views.layout
    if layout not in FIXED_LAYOUTS or len(FIXED_LAYOUTS[layout]()) <= 40:
        return layout
    return "hemisphere" if (context.views.positions[:, 2] >= 0).all() else "sphere"


register_planner("infogain", ("grid",), "Kriegel et al. 2012 over 20 views laid out like the candidates: the view whose "
                 "rays pass the most entropy of unknown voxels in the object's box before the first occupied voxel "
                 "(`nbvdata.simulation.grid.ray_information`), among those whose estimated overlap passes the rule")(
    lambda context: [InfoGainPlanner(context.config.scene_grid, context.config.sensor, context.config.views.radius,
                                     context.config.mesh.object_size, context.config.oracle.min_overlap,
                                     layout=infogain_layout(context))])
