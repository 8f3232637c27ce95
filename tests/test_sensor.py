import numpy as np
import pytest
import trimesh

from nbvdata.config import SensorConfig
from nbvdata.sensor import MeshScanner, camera_rays
from nbvdata.views import Pose

SMALL = SensorConfig(width=40, height=30)


@pytest.fixture(scope="module")
def box_scanner():
    return MeshScanner(trimesh.creation.box((0.2, 0.2, 0.2)), SMALL)


def test_camera_rays_span_the_field_of_view():
    rays = camera_rays(SMALL)
    assert rays.shape == (40 * 30, 3)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1)
    half_h = np.arctan2(rays[:, 0], rays[:, 2])
    assert np.isclose(half_h.max(), 0.385, atol=0.77 / 40)
    assert (rays[:, 2] > 0).all()


def test_box_seen_from_plus_x_returns_its_plus_x_face(box_scanner):
    scan = box_scanner.scan(Pose.look_at([0.4, 0, 0]))
    assert scan.points.dtype == np.float32 and scan.points.shape == (1200, 3)
    hits = scan.hit_points
    assert 0 < len(hits) < 1200
    np.testing.assert_allclose(hits[:, 0], 0.1, atol=1e-6)
    far = np.linalg.norm(scan.points[~scan.hit] - scan.origin, axis=1)
    np.testing.assert_allclose(far, 2 * SMALL.far, rtol=1e-6)


def test_batched_scans_equal_single_scans(box_scanner):
    poses = [Pose.look_at(p) for p in ([0.4, 0, 0], [0, 0.3, 0.2], [0.1, -0.1, 0.35])]
    batched = box_scanner.scan_many(poses)
    for pose, scan in zip(poses, batched):
        single = box_scanner.scan(pose)
        np.testing.assert_array_equal(single.points, scan.points)
        np.testing.assert_array_equal(single.hit, scan.hit)


def test_noise_is_seeded_and_needs_a_generator():
    noisy = MeshScanner(trimesh.creation.box((0.2, 0.2, 0.2)), SensorConfig(width=40, height=30, noise_std=0.002))
    pose = Pose.look_at([0.4, 0, 0])
    a = noisy.scan(pose, np.random.default_rng(7))
    b = noisy.scan(pose, np.random.default_rng(7))
    np.testing.assert_array_equal(a.points, b.points)
    assert 0.0005 < np.std(a.hit_points[:, 0]) < 0.004
    with pytest.raises(ValueError, match="Generator"):
        noisy.scan(pose)
    exact = noisy.scan_many([pose], noiseless=True)[0]
    np.testing.assert_allclose(exact.hit_points[:, 0], 0.1, atol=1e-6)


def test_near_and_far_range_limit_returns():
    mesh = trimesh.creation.box((0.2, 0.2, 0.2))
    pose = Pose.look_at([0.4, 0, 0])
    assert not MeshScanner(mesh, SensorConfig(width=8, height=6, far=0.25)).scan(pose).hit.any()
    assert not MeshScanner(mesh, SensorConfig(width=8, height=6, near=0.35)).scan(pose).hit.any()


def test_casting_only_the_rays_near_the_box_changes_no_scan():
    """The bounded cast (default) against casting every ray: the same points and hits, from
    views all round, from inside the box, and for a flat mesh (a box of zero thickness)."""
    from nbvdata.shapes import builtin_object
    from nbvdata.config import ViewConfig
    from nbvdata.views import view_sphere

    config = SensorConfig(width=88, height=72, noise_std=0.001)
    flat = trimesh.Trimesh([[-0.05, -0.05, 0], [0.05, -0.05, 0], [0, 0.05, 0]], [[0, 1, 2]])
    poses = list(view_sphere(ViewConfig(count=40, radius=0.3, layout="sphere")))
    poses.append(Pose.look_at([0.01, 0.0, 0.005], target=[0.3, 0.1, 0.0]))  # inside the mug's box
    for mesh in (builtin_object("mug").mesh, builtin_object("table_lamp").mesh, flat):
        bounded, every = MeshScanner(mesh, config), MeshScanner(mesh, config, bounded=False)
        fast = bounded.scan_many(poses, np.random.default_rng(3))
        reference = every.scan_many(poses, np.random.default_rng(3))
        assert sum(scan.hit.sum() for scan in reference) > 1000
        for a, b in zip(fast, reference):
            np.testing.assert_array_equal(a.points, b.points)
            np.testing.assert_array_equal(a.hit, b.hit)
        exact = every.scan_many(poses, noiseless=True)
        for hit_points, scan in zip(bounded.iter_hit_points(poses), exact):  # the scene's path
            np.testing.assert_array_equal(hit_points, scan.hit_points)
