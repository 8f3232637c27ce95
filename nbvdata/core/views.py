"""Candidate views on a sphere around the object, and the pose type with the authors' angles.

Camera convention (the one the authors' ``dataset_pose.npy`` follows, checked row by row):
``rotation`` is the world-to-camera matrix R = Rz(yaw) @ Ry(pitch) @ Rx(roll). Its rows are the
camera axes in world coordinates: x (image right, kept horizontal), y (image down) and z (the
optical axis). For a view looking at the centre, the third row is the unit vector from the view
towards the centre. Looking straight down, image right is world +x, as in the authors' data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nbvdata.core.config import ViewConfig
from nbvdata.core.layout_scvp import scvp_32
from nbvdata.core.layout_tammes import tammes_128
from nbvdata.core.text import plural

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))
_UP = np.array([0.0, 0.0, 1.0])
# Trigonometry that reaches the shards goes through the C library (glibc's atan2, asin, sin and
# cos are correctly rounded), not numpy's SIMD loops, whose last bit depends on the CPU (AVX-512
# or not): so the same settings give the same bytes on every machine.
_atan2, _asin, _sin, _cos = (np.vectorize(f, otypes=[np.float64]) for f in (math.atan2, math.asin, math.sin, math.cos))


def look_at_rotations(positions: np.ndarray, target: np.ndarray = np.zeros(3)) -> np.ndarray:
    """World-to-camera rotations of cameras at ``positions`` (n, 3) looking at ``target``.

    Returns (n, 3, 3) float64 with rows (x, y, z): z towards the target, x = z cross up
    (horizontal), y = z cross x (pointing down in the image).
    """
    positions = np.atleast_2d(np.asarray(positions, dtype=np.float64))
    forward = np.asarray(target, dtype=np.float64) - positions
    forward /= np.linalg.norm(forward, axis=1, keepdims=True)
    right = np.cross(forward, _UP)
    norm = np.linalg.norm(right, axis=1, keepdims=True)
    vertical = norm[:, 0] < 1e-9
    right[vertical] = (1.0, 0.0, 0.0)  # looking straight up or down: image right = world +x
    norm[vertical] = 1.0
    right /= norm
    down = np.cross(forward, right)
    return np.stack([right, down, forward], axis=1)


def angles_to_rotations(angles: np.ndarray) -> np.ndarray:
    """(n, 3) (yaw, pitch, roll) in radians -> (n, 3, 3) R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    yaw, pitch, roll = np.atleast_2d(np.asarray(angles, dtype=np.float64)).T
    cz, sz, cy, sy, cx, sx = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    return np.stack([
        np.stack([cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx], axis=-1),
        np.stack([sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx], axis=-1),
        np.stack([-sy, cy * sx, cy * cx], axis=-1),
    ], axis=1)


def rotations_to_angles(rotations: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations -> (n, 3) (yaw, pitch, roll) with R = Rz(yaw) @ Ry(pitch) @ Rx(roll).

    pitch lies in [-pi/2, pi/2]; at pitch = +-pi/2 (gimbal lock) yaw is set to 0.
    """
    r = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    pitch = -_asin(np.clip(r[:, 2, 0], -1.0, 1.0))
    locked = np.abs(r[:, 2, 0]) > 1 - 1e-12
    yaw = np.where(locked, 0.0, _atan2(r[:, 1, 0], r[:, 0, 0]))
    roll = np.where(locked, _atan2(-r[:, 1, 2], r[:, 1, 1]), _atan2(r[:, 2, 1], r[:, 2, 2]))
    return np.stack([yaw, pitch, roll], axis=1)


@dataclass(frozen=True)
class Pose:
    """A sensor pose.

    position : (3,) float64, metres, world frame
    rotation : (3, 3) float64, world-to-camera; rows = camera x, y, z axes in world coordinates
    """

    position: np.ndarray
    rotation: np.ndarray

    @classmethod
    def look_at(cls, position: np.ndarray, target: np.ndarray = np.zeros(3)) -> "Pose":
        position = np.asarray(position, dtype=np.float64).reshape(3)
        return cls(position, look_at_rotations(position[None], target)[0])

    @classmethod
    def from_xyzypr(cls, row: np.ndarray) -> "Pose":
        """From the authors' (x, y, z, yaw, pitch, roll) row."""
        row = np.asarray(row, dtype=np.float64).reshape(6)
        return cls(row[:3].copy(), angles_to_rotations(row[3:])[0])

    @property
    def direction(self) -> np.ndarray:
        """(3,) unit optical axis in world coordinates."""
        return self.rotation[2]

    @property
    def angles(self) -> np.ndarray:
        """(3,) (yaw, pitch, roll) in radians, the authors' convention."""
        return rotations_to_angles(self.rotation)[0]

    @property
    def xyzypr(self) -> np.ndarray:
        """(6,) (x, y, z, yaw, pitch, roll): the authors' pose row."""
        return np.concatenate([self.position, self.angles])

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) camera-to-world transform: columns are the camera axes, then the position."""
        matrix = np.eye(4)
        matrix[:3, :3] = self.rotation.T
        matrix[:3, 3] = self.position
        return matrix


def sphere_positions(count: int, radius: float, layout: str = "hemisphere") -> np.ndarray:
    """(count, 3) evenly spread points on a sphere (Fibonacci lattice), deterministic; for a
    layout of ``FIXED_LAYOUTS`` its directions (``count`` must be theirs) times ``radius``.

    "hemisphere" keeps z >= 0; points are equal-area in z, so spacing is uniform.
    """
    if layout in FIXED_LAYOUTS:
        directions = FIXED_LAYOUTS[layout]()
        if count != len(directions):
            raise ValueError(f"layout={layout!r} has {len(directions)} views, not {count}")
        return radius * directions
    i = np.arange(count, dtype=np.float64)
    if layout == "hemisphere":
        z = (i + 0.5) / count
    elif layout == "sphere":
        z = 1.0 - (2.0 * i + 1.0) / count
    else:
        raise ValueError(f"layout={layout!r}: must be 'hemisphere', 'sphere' or one of {', '.join(FIXED_LAYOUTS)}")
    ring = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = i * _GOLDEN_ANGLE
    return radius * np.stack([ring * _cos(phi), ring * _sin(phi), z], axis=1)


# A y-up direction (x, y, z) turned to z-up: +90 degrees about x, (x, y, z) -> (x, -z, y). A proper
# rotation (determinant +1, no mirror), the one ``mesh.up_axis: y`` applies to y-up mesh files, so
# a y-up model and y-up views keep the relation they had.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def pc_nbv_33() -> np.ndarray:
    """(33, 3) float64 unit directions of PC-NBV's 33 candidate views (Zeng et al. 2020, their
    ``viewspace_shapenet_33.txt``), turned from their y-up frame to z-up (``Y_UP_TO_Z_UP``).

    In their frame, in their order: the pole (0, 1, 0), then rings at 30, 60, 90 and 120 degrees
    from +y, 8 views each at azimuths 0, 45, ..., 315 degrees measured from +z towards +x:
    (sin t sin a, cos t, sin t cos a). Turned to z-up: the top view (0, 0, 1), 24 views at or
    above the equator and the last 8 at 30 degrees below it (elevation -30)."""
    tilt = np.radians(np.repeat([30.0, 60.0, 90.0, 120.0], 8))
    azimuth = np.radians(np.tile(np.arange(8) * 45.0, 4))
    ring = _sin(tilt)
    y_up = np.concatenate([[[0.0, 1.0, 0.0]], np.stack([ring * _sin(azimuth), _cos(tilt), ring * _cos(azimuth)],
                                                        axis=1)])
    return y_up @ Y_UP_TO_Z_UP.T


FIXED_LAYOUTS = {"pc-nbv-33": pc_nbv_33, "scvp-32": scvp_32, "tammes-128": tammes_128}  # layout -> () -> (V, 3) units


@dataclass(frozen=True)
class ViewSet:
    """Candidate views looking at the object centre.

    positions : (V, 3) float64 metres
    rotations : (V, 3, 3) float64 world-to-camera
    """

    positions: np.ndarray
    rotations: np.ndarray

    def __len__(self) -> int:
        return len(self.positions)

    def __getitem__(self, index: int) -> Pose:
        return Pose(self.positions[index], self.rotations[index])

    @property
    def unit_positions(self) -> np.ndarray:
        """(V, 3) positions as unit vectors (the regression target's form)."""
        return self.positions / np.linalg.norm(self.positions, axis=1, keepdims=True)

    def xyzypr(self) -> np.ndarray:
        """(V, 6) the authors' pose rows of every view."""
        return np.concatenate([self.positions, rotations_to_angles(self.rotations)], axis=1)


def view_sphere(config: ViewConfig = ViewConfig()) -> ViewSet:
    """The candidate view set of a config: ``count`` views on the sphere, all looking at the origin;
    with ``reach`` "hemi", only those with z >= 0 (ObjView-Bench's reachability preset), in order."""
    positions = sphere_positions(config.count, config.radius, config.layout)
    if config.reach == "hemi":
        positions = positions[positions[:, 2] >= 0]
    return ViewSet(positions, look_at_rotations(positions))


def scanned_views(positions: np.ndarray, view_units: np.ndarray) -> np.ndarray:
    """(V,) bool: the candidate views (unit directions (V, 3)) nearest in direction to each of
    the scanned sensor positions (P, 3) (object-centred; any radius). A pose on a candidate
    view marks exactly that view; a pose between views marks the nearest one."""
    taken = np.zeros(len(view_units), dtype=bool)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if len(positions):
        norms = np.linalg.norm(positions, axis=1, keepdims=True)
        directions = positions / np.where(norms > 0, norms, 1.0)
        taken[np.argmax(directions @ np.asarray(view_units, dtype=np.float64).T, axis=1)] = True
    return taken


def nearest_scan_cosines(units: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(V,) float64: for each of ``units`` (V, 3) unit directions, the cosine of the angle to its
    nearest scanned position among ``positions`` (P, 3) (object-centred, any radius); -inf with
    P = 0. Summed term by term (no BLAS), so the same on every CPU."""
    units = np.asarray(units, dtype=np.float64)
    nearest = np.full(len(units), -np.inf)
    for position in np.asarray(positions, dtype=np.float64).reshape(-1, 3):
        nearest = np.maximum(nearest, _cosines(units, position))
    return nearest


def _cosines(units: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """(V,) float64 the cosine between each of ``units`` (V, 3) float64 and ``vector`` (3,) (any
    length; a zero vector gives zeros), summed term by term in a fixed order (no BLAS, no fused
    multiply-add), so the same on every CPU."""
    x, y, z = vector
    norm = math.sqrt(x * x + y * y + z * z) or 1.0
    return (units[:, 0] * x + units[:, 1] * y + units[:, 2] * z) / norm


def farthest_view(units: np.ndarray, positions: np.ndarray) -> int:
    """The index of the view among ``units`` (V, 3) unit directions farthest in angle from its
    nearest scanned position ``positions`` (P, 3) (object-centred, any radius), skipping the views
    the positions mark (``scanned_views``); the first one when every view is marked or P = 0
    (the lowest index among equals)."""
    taken = scanned_views(positions, units)
    if not len(np.asarray(positions).reshape(-1, 3)) or taken.all():
        return 0
    return int(np.argmin(np.where(taken, np.inf, nearest_scan_cosines(units, positions))))


def spread_view(units: np.ndarray, positions: np.ndarray, direction: np.ndarray, weight: float) -> int:
    """The view among ``units`` (V, 3) not marked by ``positions`` (P, 3) with the highest
    cos(direction, view) - weight * cos(view, its nearest scanned position): a planner's answer
    ``direction`` (3,) (any length) spread away from what was scanned. Weight 0: the unmarked view
    nearest the answer; a large weight: ``farthest_view``, the answer breaking ties. The first view
    when every view is marked; the lowest index among equals. Same on every CPU."""
    units = np.asarray(units, dtype=np.float64)
    taken = scanned_views(positions, units)
    if taken.all():
        return 0
    score = _cosines(units, np.asarray(direction, dtype=np.float64).reshape(3))
    if len(np.asarray(positions).reshape(-1, 3)) and weight:
        score = score - weight * nearest_scan_cosines(units, positions)
    return int(np.argmax(np.where(taken, -np.inf, score)))


def parse_view_indices(text: str, count: int, flag: str, example: str) -> list[int]:
    """Comma-separated view indices ("3,41,120") of a view set of ``count`` -> [3, 41, 120];
    ValueError with a one-line message naming the option ``flag`` (and ``example``, a valid
    value) for a non-integer or an index outside 0..count-1."""
    try:
        indices = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise ValueError(f"{flag} {text!r}: expected comma-separated view indices, e.g. {flag} {example}") from None
    bad = [i for i in indices if not 0 <= i < count]
    if bad:
        raise ValueError(f"{flag}: indices {bad} out of range; the view set has {plural(count, 'view')} "
                         f"(0..{count - 1})")
    return indices

