"""The next-best-view from a robot's data: scans or an OctoMap in its world frame -> the network's
grid -> the NBV pose back in the world frame (``nbvtrain plan``, ``plan()``).

Two frames:

- **world**: the robot's, metres. The object's centre is at ``center``; its vertical is ``up``.
- **object**: the frame the network was trained in, nbvdata's reconstruction frame: origin at the
  object's centre, +z up, lengths in the training scene's units, where the object's largest side
  is ``mesh.object_size`` (0.136 m) and the views lie at ``views.radius`` (0.4 m).

``object = rotation @ (world - center) / k`` with ``rotation`` taking ``up`` to +z and
``k = size / mesh.object_size``, the paper's scale factor (2.5 for its robot scene): the grid's
cube (``SimConfig.scene_grid``, side ``extent``) is ``extent * k`` metres in the world, its
voxels ``extent * k / n``, and the view sphere ``radius * k``.

Scans are integrated in the object frame with nbvdata's ``OccupancyGrid``, OctoMap's exact
update (``insertPointCloud(points, origin, maxrange)``), from each scan's sensor origin. Every
point is a measured hit; a point farther from its sensor than the maximum range (default
``sensor.far * k``, the training scene's) marks nothing occupied and carves free space up to
that range, as OctoMap does: a sensor that reports its rays without a return as far points
carves the space they crossed.

An OctoMap is resampled onto the grid: a voxel's probability is that of the OctoMap leaf at its
centre, 0.5 (unknown) where the tree has no node. When the map's voxels are the grid's (same
size, the grid's corner on a key boundary, axes aligned) this is exact, voxel for voxel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from nbvdata.core.cloud import ScannedCloud
from nbvdata.core.config import SimConfig
from nbvdata.core.errors import UserError
from nbvdata.core.views import Pose, ViewSet, look_at_rotations, scanned_views, spread_view, view_sphere
from nbvdata.simulation.grid import OccupancyGrid
from nbvdata.simulation.sensor import Scan
from nbvtrain.networks.predict import NBVPrediction, Predictor, candidate_fields
from nbvtrain.planners.released import released_checkpoint
from nbvtrain.robot.sensordata import SensorScan, check_pose, read_octomap, read_scans

AXES = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1), "-x": (-1, 0, 0), "-y": (0, -1, 0), "-z": (0, 0, -1)}
UP_FIX = "give --up as x, y, z, -x, -y, -z or a vector a,b,c (write --up=-z when it starts with a minus)"


class PlanError(UserError):
    """Settings or data ``plan`` cannot use; the one-line message names the value and the fix."""


# ---------------------------------------------------------------------------------------------
# Frames


@dataclass(frozen=True)
class ObjectFrame:
    """The map between the world frame and the network's object frame.

    center : (3,) float64 object centre, world frame, metres
    rotation : (3, 3) float64 world axes -> object axes (takes the world's up to +z)
    k : world metres per object-frame unit (size / mesh.object_size)
    """

    center: np.ndarray
    rotation: np.ndarray
    k: float

    def to_object(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (N, 3) float64 object-frame points."""
        return ((np.asarray(points, dtype=np.float64) - self.center) @ self.rotation.T) / self.k

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) object-frame points -> (N, 3) float64 world points."""
        return self.center + self.k * (np.asarray(points, dtype=np.float64) @ self.rotation)

    def pose_to_world(self, pose: Pose) -> Pose:
        """An object-frame pose as a world pose (same camera, world-to-camera rotation R @ rotation)."""
        return Pose(self.to_world(pose.position[None])[0], pose.rotation @ self.rotation)

    @property
    def up(self) -> np.ndarray:
        """(3,) the world's vertical (the object frame's +z), unit."""
        return self.rotation[2].copy()


def up_rotation(up: str | np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking ``up`` (an axis name or a vector) to +z; exact (entries
    0 and +-1) for the axis names. PlanError for anything else."""
    if isinstance(up, str):
        text = up.strip().lower()
        vector = AXES.get(text) or _vector(text, "--up", UP_FIX)
    else:
        vector = up
    vector = np.asarray(vector, dtype=np.float64)
    norm = float(np.linalg.norm(vector))
    if not norm > 0:
        raise PlanError(f"--up {up}: a zero vector has no direction: {UP_FIX}")
    u = vector / norm
    axis = np.cross(u, [0.0, 0.0, 1.0])  # rotation axis times sin(angle)
    cosine = float(u[2])
    if np.linalg.norm(axis) < 1e-12:
        return np.eye(3) if cosine > 0 else np.diag([1.0, -1.0, -1.0])  # up is -z: half a turn about x
    skew = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + skew + skew @ skew / (1.0 + cosine)  # Rodrigues; exact for the axis names


def object_frame(center: np.ndarray, size: float | None, up: str | np.ndarray, config: SimConfig) -> ObjectFrame:
    """The frame of an object of largest side ``size`` metres (None: the training scene's
    ``mesh.object_size``, k = 1) centred at ``center`` in a world whose vertical is ``up``."""
    center = np.asarray(center, dtype=np.float64).reshape(3)
    if not np.isfinite(center).all():
        raise PlanError(f"--center {center.tolist()}: must be three finite numbers, metres in the world frame")
    size = config.mesh.object_size if size is None else float(size)
    if not size > 0 or not np.isfinite(size):
        raise PlanError(f"--size {size}: must be > 0 metres (the object's largest side)")
    return ObjectFrame(center, up_rotation(up), size / config.mesh.object_size)


def parse_vector(text: str, flag: str) -> np.ndarray:
    """(3,) float64 of 'x,y,z'; PlanError naming ``flag`` otherwise."""
    return _vector(text, flag, f"give {flag} as x,y,z in metres (write {flag}=-1,2,3 when it starts with a minus)")


def _vector(text: str, flag: str, fix: str) -> np.ndarray:
    try:
        values = [float(part) for part in text.replace(" ", "").split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not np.isfinite(values).all():
        raise PlanError(f"{flag} {text!r}: expected three numbers: {fix}")
    return np.array(values)


# ---------------------------------------------------------------------------------------------
# Grids


def grid_from_scans(scans: list[SensorScan], frame: ObjectFrame, config: SimConfig,
                    max_range: float | None = None) -> np.ndarray:
    """(n, n, n) float32 occupancy probabilities (0.5 = unknown) of ``scans`` integrated in the
    object frame, in order; ``max_range`` in world metres (None: ``sensor.far * k``)."""
    grid = OccupancyGrid(config.scene_grid)
    reach = config.sensor.far if max_range is None else max_range / frame.k  # in object units
    for scan in scans:
        check_world_frame(scan, frame, config)
        origin = frame.to_object(scan.origin[None])[0].astype(np.float32)
        points = frame.to_object(scan.points).astype(np.float32)
        grid.integrate(Scan(origin, points, np.ones(len(points), dtype=bool)), reach)
    return grid.probabilities()


def cloud_from_scans(scans: list[SensorScan], frame: ObjectFrame, config: SimConfig,
                     max_range: float | None = None) -> np.ndarray:
    """(M, 3) float32 every scan's points in the object frame, scan by scan in order
    (``nbvdata.core.cloud.ScannedCloud``, as the generator collects a run's hits): those inside the
    grid's cube (the generator's scene holds the object alone) and within the maximum range of
    their sensor (beyond it a point is no return, as in the grid). ``max_range`` in world metres
    (None: ``sensor.far * k``)."""
    cloud = ScannedCloud()
    reach = config.sensor.far if max_range is None else max_range / frame.k  # in object units
    half = config.scene_grid.extent / 2
    for scan in scans:
        origin = frame.to_object(scan.origin[None])[0]
        points = frame.to_object(scan.points)
        keep = (np.abs(points) <= half).all(axis=1) & (np.linalg.norm(points - origin, axis=1) <= reach)
        cloud.add(points[keep].astype(np.float32))
    return cloud.points()


def check_world_frame(scan: SensorScan, frame: ObjectFrame, config: SimConfig) -> None:
    """PlanError when a cloud looks like camera-frame points: moved by its pose (then the pose is
    camera-to-world) or by the pose's inverse (then the pose given is world-to-camera), many more
    of them fall in the object's box than as given. ``plan`` runs this before
    ``sensordata.check_pose``, which checks the pose against the cloud and would misread a
    camera-frame cloud (as an inverted pose, or points behind the sensor)."""
    half = config.scene_grid.extent / 2

    def in_box(points: np.ndarray) -> int:
        return int(np.count_nonzero((np.abs(frame.to_object(points)) < half).all(axis=1)))

    as_given = in_box(scan.points)
    inverse = np.linalg.inv(scan.matrix)
    by_pose = in_box(scan.points @ scan.matrix[:3, :3].T + scan.origin)
    by_inverse = in_box(scan.points @ inverse[:3, :3].T + inverse[:3, 3])
    if by_pose >= 10 and by_pose > 2 * as_given and by_pose >= by_inverse:
        raise PlanError(f"{scan.source}: the cloud looks like camera-frame points ({by_pose} of them fall in the "
                        f"object box once moved by the pose, {as_given} as given): give world-frame points, the cloud "
                        "transformed by its camera-to-world pose (points @ pose[:3, :3].T + pose[:3, 3]); the pose "
                        "stays as it is")
    if by_inverse >= 10 and by_inverse > 2 * as_given:
        raise PlanError(f"{scan.source}: the cloud looks like camera-frame points and the pose world-to-camera "
                        f"({by_inverse} of them fall in the object box once moved by the pose's inverse, {as_given} "
                        "as given): give world-frame points and the camera-to-world pose: with P = "
                        "np.linalg.inv(pose), the cloud transformed as points @ P[:3, :3].T + P[:3, 3], and pose P")


def grid_from_octomap(tree, frame: ObjectFrame, config: SimConfig, source: str) -> np.ndarray:
    """(n, n, n) float32 probabilities of an OcTree resampled onto the grid: each voxel takes
    the leaf at its centre, 0.5 where the tree has no node. PlanError when the centre or the
    object's box lies outside the map's known space."""
    grid = OccupancyGrid(config.scene_grid)
    low, high = np.asarray(tree.getMetricMin(), dtype=np.float64), np.asarray(tree.getMetricMax(), dtype=np.float64)
    slack = 1e-6 * tree.getResolution()
    known = f"x {low[0]:.3f}..{high[0]:.3f}, y {low[1]:.3f}..{high[1]:.3f}, z {low[2]:.3f}..{high[2]:.3f}"
    if not ((frame.center >= low - slack) & (frame.center <= high + slack)).all():
        raise PlanError(f"--center {_text(frame.center)} lies outside the map {source} (it knows {known}): give the "
                        "object's centre in the map's frame")
    corners = frame.to_world(_cube_corners(grid))
    box_low, box_high = corners.min(axis=0), corners.max(axis=0)
    if (box_low < low - slack).any() or (box_high > high + slack).any():
        raise PlanError(f"the map {source} does not cover the object box (x {box_low[0]:.3f}..{box_high[0]:.3f}, "
                        f"y {box_low[1]:.3f}..{box_high[1]:.3f}, z {box_low[2]:.3f}..{box_high[2]:.3f}; the map knows "
                        f"{known}): scan all round the object, or check --center and --size")
    centres = frame.to_world(grid.voxel_centres().reshape(-1, 3))
    probabilities = np.full(len(centres), 0.5, dtype=np.float32)
    for index, centre in enumerate(centres):
        node = tree.search(centre)
        if node is not None:
            probabilities[index] = node.getOccupancy()
    return probabilities.reshape(grid.log_odds.shape)


def octomap_aligned(tree, frame: ObjectFrame, config: SimConfig) -> bool:
    """Whether the map's voxels are the grid's (same size, corner on a key boundary, axes
    aligned), so that resampling is exact."""
    grid_config = config.scene_grid
    resolution = float(tree.getResolution())
    voxel = grid_config.resolution * frame.k
    corner = frame.to_world(_cube_corners(OccupancyGrid(grid_config))).min(axis=0) / resolution
    return (abs(voxel - resolution) <= 1e-9 * resolution and np.allclose(corner, np.round(corner), atol=1e-6)
            and np.array_equal(np.abs(frame.rotation), np.abs(np.round(frame.rotation))))


def _cube_corners(grid: OccupancyGrid) -> np.ndarray:
    """(8, 3) the grid cube's corners, object frame."""
    low, high = grid.origin, grid.origin + grid.size * grid.resolution
    return np.array([[x, y, z] for x in (low, high) for y in (low, high) for z in (low, high)])


def grid_counts(probabilities: np.ndarray) -> dict[str, int]:
    """Voxels occupied (p > 0.5), free (p < 0.5) and unknown (p = 0.5)."""
    return {"occupied": int(np.count_nonzero(probabilities > 0.5)), "free": int(np.count_nonzero(probabilities < 0.5)),
            "unknown": int(np.count_nonzero(probabilities == 0.5))}


# ---------------------------------------------------------------------------------------------
# Planners: the NBV for a grid, in the object frame


class GridPlanner(Protocol):
    """What ``plan`` asks of a network: the NBV for one grid, in the object frame.

    ``taken`` (S, 3) are the sensor positions of the scans so far, object frame (None for an
    OctoMap): a candidate-score network masks the candidates they took; the regression and
    classification networks do not use them. ``cloud`` (M, 3) every scanned point in the object
    box, object frame (``cloud_from_scans``; None for an OctoMap): what a point network reads.
    ``view_units``: a candidate-score network's (V, 3) unit candidate views, None for the others."""

    name: str
    epoch: int
    radius: float
    view_units: np.ndarray | None

    def next_view(self, grid: np.ndarray, taken: np.ndarray | None, cloud: np.ndarray | None = None) -> NBVPrediction:
        ...


class NetworkPlanner:
    """A regression or classification checkpoint (``nbvtrain.networks.predict.Predictor``)."""

    def __init__(self, predictor: Predictor):
        self.predictor = predictor
        self.name, self.epoch, self.radius = predictor.name, predictor.epoch, predictor.radius
        self.view_units = predictor.view_units

    def next_view(self, grid: np.ndarray, taken: np.ndarray | None, cloud: np.ndarray | None = None) -> NBVPrediction:
        return self.predictor.predict(grid, scans=taken)[0]


class ScorePlanner(NetworkPlanner):
    """A candidate-score checkpoint: the best-scoring candidate view not taken by a scan (each scan's
    sensor position marks its nearest candidate view, ``nbvdata.core.views.scanned_views``; an
    OctoMap has no scans, so none is marked). A point network (``nbvscore-pc``) scores from the
    scans' points instead of the grid, so it needs scans."""

    def next_view(self, grid: np.ndarray, taken: np.ndarray | None, cloud: np.ndarray | None = None) -> NBVPrediction:
        state = scanned_state(taken, self.view_units)
        if self.predictor.inputs == "points":
            if cloud is None or not len(cloud):
                raise PlanError(f"{self.name} reads the scans' points: give --scans whose points fall in the object "
                                "box (an OctoMap holds no points)")
            return self.predictor.predict(cloud, state)[0]
        return self.predictor.predict(grid, state)[0]


def scanned_state(taken: np.ndarray | None, view_units: np.ndarray | None) -> np.ndarray | None:
    """(V,) bool the candidate views the scans at ``taken`` ((S, 3) sensor positions, object
    frame) marked (``nbvdata.core.views.scanned_views``); None without scans or candidate views."""
    return None if taken is None or view_units is None else scanned_views(taken, view_units)


class RankingPlanner:
    """A ranker of candidate views (``nbvtrain.ranking.viewrank``): the view of the scene's candidate views
    (``views.*``) its per-view features score highest among those no scan marked (each scan's
    sensor position marks its nearest view; an OctoMap has no scans, so none is marked)."""

    epoch = None

    def __init__(self, ranker, config: SimConfig):
        self.ranker, self.config, self.name = ranker, config, ranker.kind
        self.views = view_sphere(config.views)
        self.radius, self.view_units = config.views.radius, self.views.unit_positions

    def next_view(self, grid: np.ndarray, taken: np.ndarray | None, cloud: np.ndarray | None = None) -> NBVPrediction:
        positions = np.zeros((0, 3)) if taken is None else np.asarray(taken, dtype=np.float64).reshape(-1, 3)
        scores = self.ranker.view_scores(grid, positions, self.views, self.config)
        scores = np.where(scanned_views(positions, self.view_units), -np.inf, scores)
        view = int(np.argmax(scores)) if np.isfinite(scores).any() else 0
        return NBVPrediction(np.array([scores[view]]), self.view_units[view], self.views[view])


class CoverPlanPlanner:
    """A set-cover model (``cover-gbm`` or ``scvp-net``, ``nbvtrain.planners.CoverPlanner``): the whole
    set of candidate views it predicts will cover the rest, in the shortest tour's order from the
    last scan (``plan``); the next view is the tour's first. An OctoMap has no scans: nothing is
    marked, and the tour starts at the set's first view."""

    epoch = None

    def __init__(self, planner, config: SimConfig):
        self.planner, self.config, self.name = planner, config, planner.name
        self.views = planner.views
        self.radius, self.view_units = config.views.radius, self.views.unit_positions
        self.plan: list[int] = []
        self.probabilities: np.ndarray | None = None

    def next_view(self, grid: np.ndarray, taken: np.ndarray | None, cloud: np.ndarray | None = None) -> NBVPrediction:
        from nbvtrain.planners import Observation

        positions = np.zeros((0, 3)) if taken is None else np.asarray(taken, dtype=np.float64).reshape(-1, 3)
        poses = ViewSet(positions, look_at_rotations(positions)) if len(positions) else []
        observation = Observation(np.asarray(grid, dtype=np.float32), tuple(poses[i] for i in range(len(positions))))
        self.probabilities = self.planner.probabilities(observation)
        self.plan = self.planner.planned_set(observation)
        view = self.plan[0]
        return NBVPrediction(np.array([self.probabilities[view]]), self.view_units[view], self.views[view])


def _cover_model_kind(path: Path) -> str | None:
    """"cover" for a cover-gbm file, "scvp-net" for a scvp-net checkpoint (by its name), else None."""
    if path.suffix.lower() == ".json" and path.is_file():
        with path.open("rb") as handle:
            return "cover" if b'"nbvtrain-cover"' in handle.read(200) else None
    return "scvp-net" if path.suffix == ".pt" and path.stem.startswith("covernet") else None


NETWORK_PLANNERS = {"regression": NetworkPlanner, "classification": NetworkPlanner, "scores": ScorePlanner}
"""Planner by the checkpoint's task."""


def load_planner(checkpoint: str | Path | None, device: str = "cpu", tta: bool = False,
                 config: SimConfig | None = None) -> GridPlanner:
    """The planner of a checkpoint or ranker file (None: the released ranker, ``viewrank``, or where
none is released the released score network; ``nbvtrain.planners.released``);
    ``tta``: quarter-turn test-time averaging where it is exact (``Predictor``; refused elsewhere,
    and for a ranker); ``config``: the scene, whose candidate views a ranker ranks."""
    from nbvtrain.planners.released import NoReleasedModel, released_ranker
    from nbvtrain.ranking.viewrank import is_ranker_file, load_ranker

    if checkpoint is not None:
        path = Path(checkpoint)
    else:  # the released ranker (ahead of the score network on the validation objects), else the score network
        try:
            path = released_ranker()
        except NoReleasedModel:
            path = released_checkpoint()
    kind = _cover_model_kind(path)
    if kind is not None:
        if tta:
            raise PlanError(f"--tta: {path} is a set-cover model, which plan runs as it is: drop --tta")
        from nbvtrain.planners import CoverModelPlanner, SCVPNetPlanner, Skipped, robot_radius

        config = config or SimConfig()
        views, radius = view_sphere(config.views), robot_radius(config)
        if kind == "cover":
            return CoverPlanPlanner(CoverModelPlanner(path, views, config, radius), config)
        try:
            return CoverPlanPlanner(SCVPNetPlanner(path, views, radius), config)
        except Skipped as reason:
            settings = "pass --set views.layout={} --set views.count={}".format(*reason.views) if reason.views else ""
            raise PlanError(reason.fix(settings)) from None
    if is_ranker_file(path):
        if tta:
            raise PlanError(f"--tta: {path} is a ranker of per-view features, which quarter turns leave unchanged "
                            "already: drop --tta")
        config = config or SimConfig()
        ranker = load_ranker(path)
        ranker.check_scene(config, str(path))
        return RankingPlanner(ranker, config)
    predictor = Predictor(path, device=device, tta=tta)
    task = predictor.model.task
    if task not in NETWORK_PLANNERS:
        raise PlanError(f"{path}: a {task} network, which plan cannot use yet: pass a "
                        f"{' or '.join(sorted(set(NETWORK_PLANNERS)))} checkpoint")
    return NETWORK_PLANNERS[task](predictor)


# ---------------------------------------------------------------------------------------------
# Planning


@dataclass(frozen=True)
class PlanResult:
    """The NBV for a robot's data, and what it was computed from.

    pose : the NBV, world frame (``Pose.matrix`` is camera-to-world)
    object_pose : the same, object frame (what the network answered)
    grid : (n, n, n) float32 the grid the network saw, 0.5 = unknown
    taken : (S, 3) scan sensor positions, object frame (None for an OctoMap)
    max_range : metres, world (None for an OctoMap)
    candidate : a score network's chosen candidate ``view`` and the ``scanned`` views the scans
        marked, as ``nbvtrain predict`` gives them (``predict.candidate_fields``); {} otherwise
    """

    pose: Pose
    object_pose: Pose
    raw: np.ndarray
    frame: ObjectFrame
    grid: np.ndarray
    config: SimConfig
    planner: GridPlanner
    source: str
    taken: np.ndarray | None = None
    max_range: float | None = None
    octomap: dict | None = None
    candidate: dict = field(default_factory=dict)

    @property
    def counts(self) -> dict[str, int]:
        return grid_counts(self.grid)

    def to_dict(self) -> dict:
        """The JSON ``nbvtrain plan`` prints: the world pose first, then what to check it by."""
        x, y, z, yaw, pitch, roll = self.pose.xyzypr.tolist()
        quaternion = Rotation.from_matrix(self.pose.matrix[:3, :3]).as_quat(canonical=True)
        grid = self.config.scene_grid
        result = {
            "position": [x, y, z], "quaternion_xyzw": quaternion.tolist(), "matrix": self.pose.matrix.tolist(),
            "yaw": yaw, "pitch": pitch, "roll": roll,
            "grid": {**self.counts, "side": grid.extent * self.frame.k, "voxel": grid.resolution * self.frame.k},
            "object": {"center": self.frame.center.tolist(), "size": self.config.mesh.object_size * self.frame.k,
                       "up": self.frame.up.tolist(), "k": self.frame.k},
            "view_radius": self.planner.radius * self.frame.k,
            "source": self.source, "model": self.planner.name, "epoch": self.planner.epoch, **self.candidate,
            "network_output": self.raw.tolist(),
        }
        if getattr(getattr(self.planner, "predictor", None), "tta", False):
            result["tta"] = True  # the answer is the mean over the grid's four quarter turns
        if self.max_range is not None:
            result["max_range"] = self.max_range
        if self.octomap is not None:
            result["octomap"] = self.octomap
        return result


def plan(center: np.ndarray, *, scans: str | Path | None = None, octomap: str | Path | None = None,
         size: float | None = None, up: str | np.ndarray = "z", checkpoint: str | Path | None = None,
         config: SimConfig | None = None, max_range: float | None = None, device: str = "cpu",
         planner: GridPlanner | None = None, tta: bool = False, spread: float | None = None) -> PlanResult:
    """The next-best-view for the object at ``center`` (world frame) from a scans file or an
    OctoMap file (exactly one), with a checkpoint's network (None: the released model; ``tta``:
    quarter-turn averaging, see ``load_planner``) or a ready ``planner``. ``config``: the training
    data's scene (None: the default scene). ``spread`` W: a regression or classification network's
    answer spread away from the scans, as ``nbvtrain evaluate --spread W`` (the candidate view of
    the scene's view sphere with the highest cos(answer, v) - W cos(v, its nearest scan),
    ``nbvdata.core.views.spread_view``); needs scans. PlanError,
    SensorDataError or CheckpointError, one line each, for unusable input."""
    config = config or SimConfig()
    if (scans is None) == (octomap is None):
        raise PlanError("give either scans (--scans FILE.yaml) or an OctoMap (--octomap MAP.bt), exactly one")
    if max_range is not None and octomap is not None:
        raise PlanError("--max-range applies to --scans only: an OctoMap's scans were integrated already")
    if spread is not None and scans is None:
        raise PlanError("--spread spreads the answer away from the scans' sensor positions, which an OctoMap does not "
                        "hold: give --scans, or drop --spread")
    if spread is not None and not (math.isfinite(spread) and spread >= 0):
        raise PlanError(f"--spread {spread}: must be a finite weight >= 0")
    if max_range is not None and not max_range > 0:
        raise PlanError(f"--max-range {max_range}: must be > 0 metres (beyond it a point only carves free space)")
    frame = object_frame(center, size, up, config)
    taken, reach, octomap_info, cloud = None, None, None, None
    if scans is not None:
        sensor_scans = read_scans(scans, check_poses=False)
        for scan in sensor_scans:  # the frame first: the pose checks misread a camera-frame cloud
            check_world_frame(scan, frame, config)
            check_pose(scan)
        reach = config.sensor.far * frame.k if max_range is None else float(max_range)
        grid = grid_from_scans(sensor_scans, frame, config, max_range)
        taken = frame.to_object(np.array([scan.origin for scan in sensor_scans]))
        cloud = cloud_from_scans(sensor_scans, frame, config, max_range)
        source = str(scans)
    else:
        tree = read_octomap(octomap)
        source = str(octomap)
        grid = grid_from_octomap(tree, frame, config, source)
        octomap_info = {"resolution": float(tree.getResolution()), "exact": bool(octomap_aligned(tree, frame, config))}
    if not (grid > 0.5).any():
        side = config.scene_grid.extent * frame.k
        raise PlanError(f"{source}: no occupied voxel in the object box ({side:.3f} m cube at --center "
                        f"{_text(frame.center)}): check --center, --size and --up, and that the data is "
                        "in the world frame")
    planner = planner or load_planner(checkpoint, device, tta, config)
    if abs(planner.radius - config.views.radius) > 1e-3 * config.views.radius:
        raise PlanError(f"the network was trained with views at {planner.radius:g} m, the scene config has "
                        f"views.radius {config.views.radius:g} m: pass the training data's scene (--config)")
    if spread is not None and planner.view_units is not None:
        raise PlanError(f"--spread: {planner.name} scores candidate views and reads the scans already: drop --spread "
                        "(it spreads a regression or classification network's answer)")
    prediction = planner.next_view(grid, taken, cloud)
    if spread is None:
        candidate = candidate_fields(planner.view_units, prediction.direction, scanned_state(taken, planner.view_units))
    else:
        views = view_sphere(config.views)
        view = spread_view(views.unit_positions, taken, prediction.direction, spread)
        prediction = NBVPrediction(prediction.raw, views.unit_positions[view], views[view])
        candidate = {"view": view, "spread": spread,
                     "scanned": np.flatnonzero(scanned_state(taken, views.unit_positions)).tolist()}
    if isinstance(planner, CoverPlanPlanner):
        candidate["plan"] = [_planned_view(frame, planner, view) for view in planner.plan]
        candidate["plan_path"] = _tour_path(taken, planner) * frame.k
    world = frame.pose_to_world(prediction.pose)
    return PlanResult(world, prediction.pose, np.asarray(prediction.raw), frame, grid, config, planner, source,
                      taken, reach, octomap_info, candidate)


def _planned_view(frame: ObjectFrame, planner: CoverPlanPlanner, view: int) -> dict:
    """One view of a cover plan for the robot: its index, world position and orientation, probability."""
    pose = frame.pose_to_world(planner.views[view])
    quaternion = Rotation.from_matrix(pose.matrix[:3, :3]).as_quat(canonical=True)
    return {"view": int(view), "position": pose.position.tolist(), "quaternion_xyzw": quaternion.tolist(),
            "probability": float(planner.probabilities[view])}


def _tour_path(taken: np.ndarray | None, planner: CoverPlanPlanner) -> float:
    """The plan's path in the object frame: from the last scan (none: the first planned view) through
    the planned views in order, round the bounding sphere (``nbvdata.core.paths``)."""
    from nbvdata.core.paths import path_lengths

    stops = planner.views.positions[planner.plan]
    if taken is not None and len(taken):
        stops = np.concatenate([np.asarray(taken, dtype=np.float64).reshape(-1, 3)[-1:], stops])
    return float(path_lengths(stops, planner.planner.radius)[-1])


def render_plan(result: PlanResult, out: str | Path) -> Path:
    """A PNG of ``draw_plan``, cropped (``nbvdata.view.render``)."""
    from nbvdata.view.render import save_cropped

    return save_cropped(draw_plan(result), out)


def draw_plan(result: PlanResult):
    """The figure of the grid the network saw, in the object frame: the candidate views (grey:
    a score network's own, else the scene's view sphere), the scans' sensor positions (green)
    and the NBV (red; for a score network its candidate view's index). The caller closes it."""
    from nbvdata.view.render import draw_state

    if result.planner.view_units is not None:
        candidates = result.planner.view_units * result.planner.radius
    else:
        candidates = view_sphere(result.config.views).positions
    taken = np.zeros((0, 3)) if result.taken is None else result.taken
    view = result.candidate.get("view")
    answer = result.object_pose.position[None] if view is None else np.zeros((0, 3))  # off the candidates
    positions = np.concatenate([candidates, taken, answer])
    views = ViewSet(positions, look_at_rotations(positions))
    scans = range(len(candidates), len(candidates) + len(taken))
    title = f"{result.planner.name}: next-best-view for {Path(result.source).name} (object frame, +z = world up)"
    return draw_state(result.grid, result.config.scene_grid.extent, views,
                      highlight=len(positions) - 1 if view is None else view, scanned=list(scans), title=title,
                      scanned_label="scans taken", candidates=len(candidates))


def _text(vector: np.ndarray) -> str:
    return ",".join(f"{v:g}" for v in vector)

