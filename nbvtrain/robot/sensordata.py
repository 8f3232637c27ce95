"""A robot's sensor data from files: point clouds, scans files (clouds with sensor poses), OctoMaps.

Everything here is in the robot's **world frame**, in metres; nothing is scaled or cropped
(``nbvtrain.robot.plan`` does that). Files come from users, so each is checked on reading and anything
unusable raises ``SensorDataError`` with one line naming the file (and the scan) and the fix.

A scans file (YAML, read with ``yaml.safe_load``) is a list of scans, each a mapping::

    - cloud: scan0.ply                 # path relative to the scans file
      pose: [[r11, r12, r13, x], [r21, r22, r23, y], [r31, r32, r33, z], [0, 0, 0, 1]]
    - cloud: scan1.npy
      position: [x, y, z]              # the sensor's optical centre
      quaternion_xyzw: [qx, qy, qz, qw]

``pose`` is the 4x4 camera-to-world transform, ``position`` + ``quaternion_xyzw`` the same
transform as a translation and a unit quaternion (x, y, z, w order, scalar last, as ROS). The
camera frame is the project's: +z along the optical axis, +x image right, +y image down (ROS
``*_optical_frame``). Clouds are the scan's points **in the world frame**. ``check_pose``
checks each scan's pose against its cloud (docs/robot-pose-checks.md says what that catches and
what it cannot): (almost) all points must lie in front of the sensor, which many inverted
(world-to-camera) poses and poses of a body frame with x forward fail; and a pose is refused as
inverted when its inverse explains the cloud as a range scan and the pose itself does not: seen
from the inverse, the points lie on a depth image's pixel rays (they share image columns and rows)
or hide none behind others. ``nbvtrain.robot.plan`` first refuses a cloud that lands in the object's box
only once moved by its pose or by the pose's inverse (camera-frame points of a sensor looking at
the object, which the pose checks would misread, e.g. as an inverted pose)."""

from __future__ import annotations

import contextlib
import difflib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from nbvdata.core.errors import UserError
from nbvdata.core.text import plural
from nbvdata.core.userarrays import NpyError, read_npy

CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz", ".npy")
OCTOMAP_SUFFIXES = (".bt", ".ot")
RIGID_TOLERANCE = 1e-4
"""Largest |R^T R - I| entry of a pose's rotation, and |norm - 1| of a quaternion, accepted
(a matrix typed with 5 decimals passes; a scaled or sheared one does not)."""
BEHIND_TOLERANCE = 0.01
"""Largest share of a cloud's points allowed at or behind its sensor's image plane."""
PIXEL_RAYS = 0.8
"""Share of a cloud's points on a shared image column or row (``pixel_ray_share``) from which a
pose sees the cloud as a depth image's pixels: a scan straight from a depth image has 0.85 or
more from its own pose (0.96 whole, 0.87 with 70 % of the points dropped at random) and at most
0.45 from its inverse (every viewpoint, object and world placement tried: benchmarks/pose_checks.py)."""
HIDDEN_REFUSED, HIDDEN_NONE = 0.02, 0.002
"""A pose is refused as inverted when at least HIDDEN_REFUSED of the points lie hidden behind
others as seen from it (``hidden_share``) and at most HIDDEN_NONE from its inverse. A range scan
seen from its own sensor hides none, 0.0035 at most with the far points of rays without a return
(whole, thinned, cropped and voxel-filtered clouds tried: benchmarks/pose_checks.py)."""
POSE_SAMPLE = 20_000
"""Points the pose statistics look at (every k-th point of a larger cloud)."""
POSE_MIN_POINTS = 100
"""Fewer points than this say nothing about the pose: only the in-front check applies."""
INVERTED_FIX = ("give the camera-to-world pose, the inverse of this one (np.linalg.inv of the 4x4; as position + "
                "quaternion_xyzw, the camera's position and orientation in the world)")
SCAN_KEYS = ("cloud", "pose", "position", "quaternion_xyzw")
POSE_FIX = "give pose: a 4x4 camera-to-world matrix, or position: [x, y, z] and quaternion_xyzw: [x, y, z, w]"
NO_NAN_FIX = ("drop them (pixels without a return), e.g. points[np.isfinite(points).all(axis=1)]; a ray without a "
              "return may instead carry a point beyond the maximum range along it, which carves free space")


class SensorDataError(UserError):
    """A cloud, scans file or OctoMap that cannot be used; the one-line message names the fix."""


@dataclass(frozen=True)
class SensorScan:
    """One range scan in the world frame.

    points : (N, 3) float64 metres, world frame (N >= 1, all finite)
    matrix : (4, 4) float64 camera-to-world transform of the sensor (rigid)
    source : where it came from, for messages ("scans.yaml: scan 2 (a.ply)")
    """

    points: np.ndarray
    matrix: np.ndarray
    source: str

    @property
    def origin(self) -> np.ndarray:
        """(3,) float64 the sensor's optical centre, world frame: where its rays start."""
        return self.matrix[:3, 3]


# ---------------------------------------------------------------------------------------------
# Point clouds


def read_cloud(path: str | Path) -> np.ndarray:
    """(N, 3) float64 points of a .ply, .pcd, .xyz or .npy file (N >= 1, all finite).

    .npy: an (N, 3) array of floats. .xyz: text, one point a line, x y z first (further columns,
    e.g. normals, are ignored). .ply: the vertices (ascii or binary; a mesh's vertices too).
    .pcd: the x, y, z fields (ascii, binary or binary_compressed)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise SensorDataError(f"{path}: unsupported point cloud format '{path.suffix}': use one of "
                              f"{', '.join(CLOUD_SUFFIXES)}")
    if not path.is_file():
        raise SensorDataError(f"{path}: no such point cloud file: check the path")
    reader = {".npy": _read_npy, ".xyz": _read_xyz, ".ply": _read_ply, ".pcd": _read_pcd}[suffix]
    points = reader(path)
    if points.ndim != 2 or points.shape[1] != 3:
        raise SensorDataError(f"{path}: holds an array of shape {points.shape}, not (N, 3) points")
    if len(points) == 0:
        raise SensorDataError(f"{path}: holds no points: pass the scan's points (N >= 1)")
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise SensorDataError(f"{path}: {int(bad.sum())} of {plural(len(points), 'point')} hold NaN or infinite "
                              f"coordinates: {NO_NAN_FIX}")
    return points


def _read_npy(path: Path) -> np.ndarray:
    try:
        array = read_npy(path)
    except NpyError as error:
        raise SensorDataError(f"{error} (one (N, 3) float array)") from None
    if array.dtype.kind not in "fiu":
        raise SensorDataError(f"{path}: holds dtype {array.dtype}: np.save one (N, 3) float array")
    return array.astype(np.float64)


def _read_xyz(path: Path) -> np.ndarray:
    try:
        array = np.loadtxt(path, dtype=np.float64, ndmin=2, comments="#")
    except (OSError, ValueError, UnicodeDecodeError) as error:
        raise SensorDataError(f"{path}: not a readable .xyz text file ({_first_line(error)}): write one point a "
                              "line, 'x y z'") from None
    if array.size and array.shape[1] < 3:
        raise SensorDataError(f"{path}: has {array.shape[1]} numbers a line: write one point a line, 'x y z'")
    return array[:, :3] if array.size else array.reshape(0, 3)


def _read_ply(path: Path) -> np.ndarray:
    import trimesh

    with path.open("rb") as handle:
        head = handle.read(5)
        if not (head.startswith(b"ply\n") or head == b"ply\r\n"):
            raise SensorDataError(f"{path}: not a PLY file (it does not start with 'ply'): pass a .ply point cloud")
    try:
        loaded = trimesh.load(path, file_type="ply", process=False)
    except Exception as error:  # trimesh's parser fails in many ways on a broken file
        raise SensorDataError(f"{path}: not a readable PLY file ({_first_line(error)}): save the cloud again") from None
    vertices = getattr(loaded, "vertices", None)
    if vertices is None:  # a PLY without vertices loads as an empty scene
        return np.zeros((0, 3))
    return np.asarray(vertices, dtype=np.float64)


def _read_pcd(path: Path) -> np.ndarray:
    """x, y, z of a PCD file (PCL's format), read here for ascii and binary data and through
    open3d for binary_compressed, always checked against the header's point count."""
    raw = path.read_bytes()
    header: dict[str, list[str]] = {}
    offset = 0
    while True:
        end = raw.find(b"\n", offset)
        if end < 0:
            raise SensorDataError(f"{path}: not a PCD file (no DATA line in its header): pass a .pcd point cloud")
        line = raw[offset:end].decode("ascii", "replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            break
    try:
        fields, sizes, types = header["FIELDS"], [int(s) for s in header["SIZE"]], header["TYPE"]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
        points = int(header["POINTS"][0])
        data = header["DATA"][0].lower()
    except (KeyError, ValueError, IndexError):
        raise SensorDataError(f"{path}: not a PCD file (its header lacks FIELDS, SIZE, TYPE or POINTS)") from None
    if not {"x", "y", "z"} <= set(fields) or not len(fields) == len(sizes) == len(types) == len(counts):
        raise SensorDataError(f"{path}: a PCD file without x, y, z fields (it has {' '.join(fields)})")
    if data == "binary_compressed":
        return _read_pcd_compressed(path, points)
    if data == "ascii":
        try:
            table = np.loadtxt(raw[offset:].decode("ascii").splitlines(), dtype=np.float64, ndmin=2)
        except ValueError as error:
            raise SensorDataError(f"{path}: PCD data not readable ({_first_line(error)})") from None
        columns = np.cumsum([0] + counts)
        if len(table) != points or (points and table.shape[1] != columns[-1]):
            raise SensorDataError(f"{path}: PCD data holds {table.shape} values, the header says {points} points of "
                                  f"{columns[-1]} values (truncated?): save the cloud again")
        return np.stack([table[:, columns[fields.index(axis)]] for axis in "xyz"], axis=1)
    if data != "binary":
        raise SensorDataError(f"{path}: PCD DATA '{data}' is not ascii, binary or binary_compressed")
    kinds = {"F": "f", "I": "i", "U": "u"}
    try:
        # Fields by position: PCL pads with several fields named "_", which a dtype cannot hold.
        dtype = np.dtype([(f"f{i}", f"<{kinds[kind]}{size}", (count,)) for i, (size, kind, count)
                          in enumerate(zip(sizes, types, counts))])
    except (KeyError, TypeError):
        raise SensorDataError(f"{path}: PCD field types {types} / sizes {sizes} are not valid") from None
    if len(raw) - offset < points * dtype.itemsize:
        raise SensorDataError(f"{path}: PCD data holds {len(raw) - offset} bytes, {points} points need "
                              f"{points * dtype.itemsize} (truncated?): save the cloud again")
    table = np.frombuffer(raw, dtype=dtype, count=points, offset=offset)
    return np.stack([table[f"f{fields.index(axis)}"][:, 0].astype(np.float64) for axis in "xyz"], axis=1)


def _read_pcd_compressed(path: Path, points: int) -> np.ndarray:
    from nbvdata.simulation._open3d import open3d as o3d

    with _captured_stderr(), o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        cloud = o3d.io.read_point_cloud(str(path), format="pcd", remove_nan_points=False,
                                        remove_infinite_points=False)
    array = np.asarray(cloud.points, dtype=np.float64)
    if len(array) != points:
        raise SensorDataError(f"{path}: compressed PCD data gave {len(array)} points, the header says {points} "
                              "(truncated or corrupt?): save the cloud again")
    return array


# ---------------------------------------------------------------------------------------------
# Scans files


def read_scans(path: str | Path, check_poses: bool = True) -> list[SensorScan]:
    """The scans a scans file lists (see the module docstring), each checked; SensorDataError
    naming the file, the scan and the fix for anything unusable. ``check_poses=False`` leaves out
    ``check_pose`` (every pose is still read and checked rigid), for a caller that runs it after
    checks of its own (``nbvtrain.robot.plan`` first looks for camera-frame clouds)."""
    path = Path(path)
    if not path.is_file():
        raise SensorDataError(f"{path}: no such scans file: check the --scans path")
    try:
        entries = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise SensorDataError(f"{path}: not a valid YAML scans file ({_first_line(error)})") from None
    if not isinstance(entries, list) or not entries:
        raise SensorDataError(f"{path}: a scans file is a non-empty YAML list of scans, each "
                              "{cloud: PATH, pose: 4x4} or {cloud: PATH, position: [x, y, z], quaternion_xyzw: [...]}")
    return [_read_scan(entry, path, number, check_poses) for number, entry in enumerate(entries, start=1)]


def _read_scan(entry: object, path: Path, number: int, check_poses: bool) -> SensorScan:
    where = f"{path}: scan {number}"
    if not isinstance(entry, dict):
        raise SensorDataError(f"{where} is {str(entry)[:40]!r}, not a mapping: {{cloud: PATH, pose: 4x4 matrix}}")
    for key in entry:
        if key not in SCAN_KEYS:
            close = difflib.get_close_matches(str(key), SCAN_KEYS, n=1)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            raise SensorDataError(f"{where}: unknown key '{key}'{hint} (known: {', '.join(SCAN_KEYS)})")
    if "cloud" not in entry or not isinstance(entry["cloud"], str):
        raise SensorDataError(f"{where}: no cloud: give cloud: PATH (relative to {path.name})")
    matrix = camera_to_world(entry, where)
    cloud = path.parent / entry["cloud"]
    try:
        points = read_cloud(cloud)
    except SensorDataError as error:
        raise SensorDataError(f"{where}: {error}") from None
    scan = SensorScan(points, matrix, f"{where} ({entry['cloud']})")
    if check_poses:
        check_pose(scan)
    return scan


def camera_to_world(entry: dict, where: str) -> np.ndarray:
    """(4, 4) float64 camera-to-world transform of a scan entry's ``pose`` or ``position`` +
    ``quaternion_xyzw``; SensorDataError when missing, malformed or not rigid."""
    has_pose, has_position = "pose" in entry, "position" in entry or "quaternion_xyzw" in entry
    if has_pose and has_position:
        raise SensorDataError(f"{where}: both pose and position/quaternion_xyzw: give one of them")
    if not has_pose and not has_position:
        raise SensorDataError(f"{where}: no sensor pose: {POSE_FIX}")
    if has_pose:
        matrix = _numbers(entry["pose"], (4, 4), f"{where}: pose", POSE_FIX)
        if np.abs(matrix[3] - [0, 0, 0, 1]).max() > RIGID_TOLERANCE:
            raise SensorDataError(f"{where}: pose's last row {matrix[3].tolist()} is not [0, 0, 0, 1]: give the 4x4 "
                                  "camera-to-world matrix")
        check_rotation(matrix[:3, :3], f"{where}: pose")
        matrix[3] = [0.0, 0.0, 0.0, 1.0]
        return matrix
    if "position" not in entry or "quaternion_xyzw" not in entry:
        raise SensorDataError(f"{where}: position and quaternion_xyzw go together: {POSE_FIX}")
    position = _numbers(entry["position"], (3,), f"{where}: position", POSE_FIX)
    quaternion = _numbers(entry["quaternion_xyzw"], (4,), f"{where}: quaternion_xyzw", POSE_FIX)
    norm = float(np.linalg.norm(quaternion))
    if abs(norm - 1.0) > RIGID_TOLERANCE:
        raise SensorDataError(f"{where}: quaternion_xyzw {quaternion.tolist()} has norm {norm:.6g}, not 1: give a unit "
                              "quaternion in (x, y, z, w) order")
    from scipy.spatial.transform import Rotation

    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat(quaternion / norm).as_matrix()
    matrix[:3, 3] = position
    return matrix


def check_rotation(rotation: np.ndarray, where: str) -> None:
    """SensorDataError unless (3, 3) ``rotation`` is a proper rotation (within RIGID_TOLERANCE)."""
    error = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
    if error > RIGID_TOLERANCE:
        raise SensorDataError(f"{where} is not a rigid transform (its 3x3 part is off orthonormal by {error:.3g}): "
                              "give a rotation and a translation, without scale or shear, to 5 or more decimals")
    if np.linalg.det(rotation) < 0:
        raise SensorDataError(f"{where} is a reflection (determinant -1), not a rigid transform: a camera-to-world "
                              "rotation keeps a right-handed frame")


def check_pose(scan: SensorScan) -> None:
    """SensorDataError when the scan's pose does not fit its cloud: points behind the sensor
    (``check_in_front``), or a pose whose inverse explains the cloud as a range scan and which
    itself does not (an inverted, world-to-camera, pose): seen from the inverse the points lie on a
    depth image's pixel rays (``pixel_ray_share`` >= PIXEL_RAYS) and from the pose not, or from the
    pose they hide others (``hidden_share`` >= HIDDEN_REFUSED) and from the inverse hardly any
    (<= HIDDEN_NONE). A pose that fits is cheap to accept: a depth image's cloud on its pixel rays
    needs no more. Clouds of fewer than POSE_MIN_POINTS points get the in-front check only."""
    check_in_front(scan)
    if len(scan.points) < POSE_MIN_POINTS:
        return
    points = scan.points[::-(-len(scan.points) // POSE_SAMPLE)]
    given = pixel_ray_share(points, scan.matrix)
    if given >= PIXEL_RAYS:
        return
    inverse = np.linalg.inv(scan.matrix)
    if in_front_share(points, inverse) < 1 - BEHIND_TOLERANCE:
        return  # the inverse is no range scan's pose either
    inverted = pixel_ray_share(points, inverse)
    if inverted >= PIXEL_RAYS:
        raise SensorDataError(
            f"{scan.source}: the pose looks inverted (world-to-camera): seen from its inverse the points lie on a "
            f"depth image's pixel rays ({inverted:.0%} share an image column or row with others, {given:.0%} as "
            f"given): {INVERTED_FIX}")
    hidden = hidden_share(points, scan.origin)
    if hidden >= HIDDEN_REFUSED:
        unhidden = hidden_share(points, inverse[:3, 3])
        if unhidden <= HIDDEN_NONE:
            raise SensorDataError(
                f"{scan.source}: the pose looks inverted (world-to-camera): from its sensor {hidden:.1%} of the points "
                f"lie hidden behind others, which a range scan cannot measure; from its inverse's {unhidden:.1%}: "
                f"{INVERTED_FIX}")


def in_front_share(points: np.ndarray, matrix: np.ndarray) -> float:
    """The share of (N, 3) world points in front of the image plane of the camera-to-world
    ``matrix`` (4, 4): depth = (point - origin) . optical axis > 0."""
    return float(np.count_nonzero(_depths(points, matrix) > 0)) / len(points)


def _depths(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """(N,) depths of (N, 3) world points along the optical axis of the camera-to-world ``matrix``."""
    return (points - matrix[:3, 3]) @ matrix[:3, 2]


def check_in_front(scan: SensorScan) -> None:
    """SensorDataError unless (almost) all points lie in front of the scan's sensor.

    A range camera measures only in front of its image plane: depth = (point - origin) . optical
    axis > 0. World-frame points with their camera-to-world pose pass; points in the camera frame
    (or a pose inverted, or of a frame whose x is forward) often put many behind."""
    behind = len(scan.points) - int(np.count_nonzero(_depths(scan.points, scan.matrix) > 0))
    if behind > BEHIND_TOLERANCE * len(scan.points):
        front = in_front_share(scan.points, np.linalg.inv(scan.matrix))
        if front >= 1 - BEHIND_TOLERANCE:  # the pose's inverse puts them in front: the likelier mistake
            raise SensorDataError(
                f"{scan.source}: {behind} of {len(scan.points)} points ({behind / len(scan.points):.0%}) lie behind the "
                f"sensor of its pose, and {front:.0%} in front of its inverse's: the pose looks inverted "
                f"(world-to-camera); tell by the depths (points - pose[:3, 3]) @ pose[:3, 2], which a "
                f"camera-to-world pose makes positive: {INVERTED_FIX}")
        raise SensorDataError(
            f"{scan.source}: {behind} of {len(scan.points)} points ({behind / len(scan.points):.0%}) lie behind the "
            "sensor of its pose (and of its inverse's): the cloud must hold world-frame points and the pose be "
            "camera-to-world with the optical axis along the camera's +z (x right, y down), so that the depths "
            "(points - pose[:3, 3]) @ pose[:3, 2] are positive; transform a camera-frame cloud by its pose first, and "
            "invert a world-to-camera pose")


def pixel_ray_share(points: np.ndarray, matrix: np.ndarray) -> float:
    """How far (N, 3) world points look like a depth image's pixels seen from the camera-to-world
    ``matrix``: the larger share, over image columns and rows, of points whose image coordinate
    (x / z, resp. y / z in the camera frame) another point repeats to within a thousandth of the
    pixel spacing (the median distance between neighbouring points in the image plane).

    A depth image deprojected through its pixels puts every point of an image column on one plane
    through the sensor, so its own pose gives nearly 1 (all but one point per column); seen from
    anywhere else a column is no plane through the sensor and the coordinates spread, giving about
    0.1. Points behind the image plane are left out. 0 for fewer than 3 points in front."""
    from scipy.spatial import cKDTree

    camera = (points - matrix[:3, 3]) @ matrix[:3, :3]  # world -> camera frame (rotation transposed)
    camera = camera[camera[:, 2] > 0]
    if len(camera) < 3:
        return 0.0
    image = camera[:, :2] / camera[:, 2:]
    spacing = cKDTree(image).query(image, k=2)[0][:, 1]
    spacing = spacing[spacing > 0]
    if not len(spacing):
        return 0.0
    tolerance = 1e-3 * float(np.median(spacing))
    return max(float(np.mean(np.diff(np.sort(coordinate)) < tolerance)) for coordinate in image.T)


def hidden_share(points: np.ndarray, origin: np.ndarray) -> float:
    """The share of (N, 3) points that lie behind another point as seen from ``origin`` (3,):
    within a quarter of the cloud's point spacing s (the median distance between neighbours) of
    its line of sight, and more than 5 s nearer. A range sensor measures the first surface along
    each ray, so its scan seen from its own origin hides (almost) none."""
    from scipy.spatial import cKDTree

    spacing = float(np.median(cKDTree(points).query(points, k=2)[0][:, 1]))
    rays = points - origin
    ranges = np.linalg.norm(rays, axis=1)
    keep = ranges > 0
    rays, ranges = rays[keep] / ranges[keep, None], ranges[keep]
    if len(ranges) < 2 or not spacing > 0:
        return 0.0
    angles, neighbours = cKDTree(rays).query(rays, k=min(9, len(rays)))
    near = angles[:, 1:] < 0.25 * spacing / ranges[:, None]  # chord of unit vectors ~ angle
    nearer = ranges[neighbours[:, 1:]] < ranges[:, None] - 5 * spacing
    return float(np.mean((near & nearer).any(axis=1)))


def _numbers(value: object, shape: tuple[int, ...], where: str, fix: str) -> np.ndarray:
    """``value`` as a float64 array of ``shape``; numbers may be YAML numbers or numeric strings
    (PyYAML reads 1e-3 as a string)."""
    try:
        array = np.array(value, dtype=object)
        if array.shape != shape or any(isinstance(v, bool) for v in array.flat):
            raise ValueError
        array = np.array([float(v) for v in array.flat], dtype=np.float64).reshape(shape)
    except (ValueError, TypeError):
        raise SensorDataError(f"{where} is {str(value)[:60]!r}, not {' x '.join(map(str, shape))} numbers: "
                              f"{fix}") from None
    if not np.isfinite(array).all():
        raise SensorDataError(f"{where} holds NaN or infinite values: {fix}")
    return array


# ---------------------------------------------------------------------------------------------
# OctoMaps

OCTOMAP_HEADERS = {".bt": b"# Octomap OcTree binary file", ".ot": b"# Octomap OcTree file"}


def read_octomap(path: str | Path):
    """The OcTree of a .bt (binary: occupied/free only) or .ot (full probabilities) file, read with
    pyoctomap; SensorDataError naming the file for anything else."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in OCTOMAP_SUFFIXES:
        raise SensorDataError(f"{path}: not an OctoMap file name (.bt or .ot): pass a map written by OctoMap "
                              "(octomap_saver, OcTree.writeBinary or write)")
    if not path.is_file():
        raise SensorDataError(f"{path}: no such OctoMap file: check the --octomap path")
    try:
        import pyoctomap
    except ImportError:
        raise SensorDataError("reading OctoMaps needs pyoctomap, which is not installed: pip install pyoctomap, "
                              "or pass the scans (--scans)") from None
    with path.open("rb") as handle:
        first = handle.readline().rstrip(b"\r\n")
    if first != OCTOMAP_HEADERS[suffix]:
        other = next((s for s, h in OCTOMAP_HEADERS.items() if h == first), None)
        expected = OCTOMAP_HEADERS[suffix].decode()
        hint = f"it is a {other} file: rename it" if other else f"it does not start with '{expected}'"
        raise SensorDataError(f"{path}: not an OctoMap {suffix} file ({hint})")
    with _captured_stderr() as messages:
        if suffix == ".bt":
            tree = pyoctomap.OcTree(0.1)
            tree = tree if tree.readBinary(str(path)) else None
        else:
            tree = pyoctomap.OcTree(0.1).read(str(path))
    if tree is None or not hasattr(tree, "search"):
        said = ("".join(messages).strip().splitlines() or ["it could not be read"])[-1]
        raise SensorDataError(f"{path}: not a readable OctoMap ({said.removeprefix('ERROR: ')[:80]}): write it "
                              "again with OctoMap")
    if tree.size() == 0:
        raise SensorDataError(f"{path}: the OctoMap holds no nodes: integrate scans into it first")
    return tree


@contextlib.contextmanager
def _captured_stderr():
    """Hold what C++ libraries print on file descriptor 2 (OctoMap's and RPly's messages), so a
    bad file ends in our one line; the yielded list holds the text after the block."""
    captured: list[str] = []
    saved = os.dup(2)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield captured
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            captured.append(sink.read().decode("utf-8", "replace"))


def _first_line(error: BaseException) -> str:
    return (str(error).strip().splitlines() or [type(error).__name__])[0][:80]
