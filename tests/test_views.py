import io
import math
import zipfile

import numpy as np
import pytest
from conftest import DATASET, need
from scipy.spatial import cKDTree

from nbvdata.core.config import ViewConfig
from nbvdata.core.views import Pose, angles_to_rotations, look_at_rotations, rotations_to_angles, view_sphere


@pytest.mark.parametrize("layout", ["hemisphere", "sphere"])
@pytest.mark.parametrize("count", [1, 20, 500, 2000])
def test_views_on_the_sphere_look_at_the_centre(layout, count):
    views = view_sphere(ViewConfig(radius=0.4, count=count, layout=layout))
    assert len(views) == count
    np.testing.assert_allclose(np.linalg.norm(views.positions, axis=1), 0.4)
    if layout == "hemisphere":
        assert (views.positions[:, 2] >= 0).all()
    np.testing.assert_allclose(views.rotations[:, 2], -views.unit_positions, atol=1e-12)
    identity = np.einsum("vij,vkj->vik", views.rotations, views.rotations)
    np.testing.assert_allclose(identity, np.broadcast_to(np.eye(3), identity.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(views.rotations), 1.0)


@pytest.mark.parametrize("layout", ["hemisphere", "sphere"])
def test_views_are_evenly_spread_and_deterministic(layout):
    views = view_sphere(ViewConfig(count=500, layout=layout))
    spacing = cKDTree(views.positions).query(views.positions, k=2)[0][:, 1]
    assert spacing.min() > 0.6 * np.median(spacing)
    assert spacing.max() < 1.6 * np.median(spacing)
    np.testing.assert_array_equal(views.positions, view_sphere(ViewConfig(count=500, layout=layout)).positions)


def test_image_right_is_horizontal_and_image_down_points_down():
    views = view_sphere(ViewConfig(count=300))
    not_top = np.abs(views.unit_positions[:, 2]) < 0.999
    np.testing.assert_allclose(views.rotations[not_top, 0, 2], 0, atol=1e-12)
    assert (views.rotations[not_top, 1, 2] < 0).all()
    top = look_at_rotations(np.array([[0, 0, 0.4]]))[0]
    np.testing.assert_allclose(top, np.diag([1.0, -1.0, -1.0]), atol=1e-12)


def test_angle_round_trips(rng):
    angles = rng.uniform([-np.pi, -np.pi / 2 + 1e-3, -np.pi], [np.pi, np.pi / 2 - 1e-3, np.pi], (1000, 3))
    np.testing.assert_allclose(rotations_to_angles(angles_to_rotations(angles)), angles, atol=1e-9)
    rotations = view_sphere(ViewConfig(count=500, layout="sphere")).rotations
    np.testing.assert_allclose(angles_to_rotations(rotations_to_angles(rotations)), rotations, atol=1e-9)
    pose = Pose.look_at(np.array([0.1, -0.2, 0.3]))
    again = Pose.from_xyzypr(pose.xyzypr)
    np.testing.assert_allclose(again.rotation, pose.rotation, atol=1e-12)
    np.testing.assert_allclose(pose.matrix[:3, :3] @ np.array([0, 0, 1.0]), pose.direction)
    np.testing.assert_allclose(pose.matrix[:3, 3], pose.position)
    views = view_sphere(ViewConfig(count=50))
    rows = views.xyzypr()
    assert rows.shape == (50, 6)
    np.testing.assert_allclose(angles_to_rotations(rows[:, 3:]), views.rotations, atol=1e-12)
    np.testing.assert_array_equal(rows[:, :3], views.positions)


def test_gimbal_lock_rows_round_trip():
    rotations = angles_to_rotations(np.array([[0.3, np.pi / 2, 0.1], [0.0, -np.pi / 2, 0.7]]))
    np.testing.assert_allclose(angles_to_rotations(rotations_to_angles(rotations)), rotations, atol=1e-9)


def _authors_poses() -> np.ndarray:
    with zipfile.ZipFile(need(DATASET / "dataset_pose.zip")) as archive:
        name = next(n for n in archive.namelist() if n.endswith(".npy"))
        return np.load(io.BytesIO(archive.read(name)))


def test_agrees_with_every_row_of_the_authors_poses():
    rows = _authors_poses()
    assert rows.shape == (15166, 6)
    theirs = angles_to_rotations(rows[:, 3:])
    ours = look_at_rotations(rows[:, :3])
    # The third row (optical axis towards the centre) agrees on every row.
    np.testing.assert_allclose(theirs[:, 2], ours[:, 2], atol=1e-4)
    # The whole camera frame agrees wherever the authors' angles are not in gimbal lock
    # (pitch = +-pi/2, where their yaw/roll split is arbitrary).
    regular = np.abs(np.abs(rows[:, 4]) - np.pi / 2) > 1e-6
    assert regular.sum() > 15000
    np.testing.assert_allclose(theirs[regular], ours[regular], atol=1e-4)
    # Our angles reproduce our rotations for every row.
    np.testing.assert_allclose(angles_to_rotations(rotations_to_angles(ours)), ours, atol=1e-9)


def test_angles_and_positions_are_the_c_librarys_bits():
    """Shards hold these values, so they must not depend on the CPU: numpy's SIMD arctan2 differs
    in the last bit between CPUs with and without AVX-512 (on some of these 500 views), glibc's
    correctly rounded atan2/asin/sin/cos do not."""
    views = view_sphere(ViewConfig(count=500))
    r = views.rotations
    angles = views.xyzypr()[:, 3:]
    expected_yaw = [math.atan2(row[1, 0], row[0, 0]) for row in r]
    expected_pitch = [-math.asin(min(1.0, max(-1.0, row[2, 0]))) for row in r]
    assert angles[:, 0].tolist() == expected_yaw and angles[:, 1].tolist() == expected_pitch
    i = np.arange(500.0)
    phi = i * (np.pi * (3.0 - np.sqrt(5.0)))
    ring = np.sqrt(1.0 - ((i + 0.5) / 500) ** 2)
    assert views.positions[:, 0].tolist() == (0.4 * (ring * np.array([math.cos(p) for p in phi]))).tolist()
