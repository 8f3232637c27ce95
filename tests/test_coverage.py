import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from nbvdata.core.config import CoverageConfig, SensorConfig, ViewConfig
from nbvdata.core.views import Pose, view_sphere
from nbvdata.simulation.coverage import SurfaceCoverage
from nbvdata.simulation.sensor import MeshScanner
from nbvdata.simulation.shapes import builtin_object


@pytest.fixture(scope="module")
def mug():
    return builtin_object("mug")


@pytest.mark.parametrize("metric", ["euclidean", "box"])
def test_matching_agrees_with_a_brute_force_kd_tree(mug, metric):
    coverage = SurfaceCoverage(mug.mesh, CoverageConfig(points=4000, metric=metric), np.random.default_rng(0))
    scanner = MeshScanner(mug.mesh, SensorConfig(width=60, height=50))
    views = view_sphere(ViewConfig(count=12, layout="sphere"))
    threshold = coverage.config.threshold
    for scan in scanner.scan_many(views):
        points = scan.hit_points.astype(np.float64)
        if metric == "euclidean":
            distance = cKDTree(points).query(coverage.points)[0]
            expected = distance <= threshold
        else:
            distance = cKDTree(points).query(coverage.points, p=np.inf)[0]
            expected = distance < threshold
        np.testing.assert_array_equal(coverage.covered_by(points), expected)


def test_reference_points_are_seeded_and_on_the_surface():
    box = trimesh.creation.box((0.2, 0.1, 0.1))
    a = SurfaceCoverage(box, CoverageConfig(points=2000), np.random.default_rng(3))
    b = SurfaceCoverage(box, CoverageConfig(points=2000), np.random.default_rng(3))
    np.testing.assert_array_equal(a.points, b.points)
    on_face = np.isclose(np.abs(a.points) / [0.1, 0.05, 0.05], 1.0).any(axis=1)
    assert on_face.all() and (np.abs(a.points) <= np.array([0.1, 0.05, 0.05]) + 1e-12).all()
    # uniform in area: the two 0.2 x 0.1 faces at +-y hold 0.04 of the 0.1 m^2 surface
    share_y = np.isclose(np.abs(a.points[:, 1]), 0.05).mean()
    assert share_y == pytest.approx(0.4, abs=0.05)


def test_coverage_grows_and_observable_coverage_reaches_one():
    obj = builtin_object("pill")
    coverage = SurfaceCoverage(obj.mesh, CoverageConfig(points=3000), np.random.default_rng(0))
    scanner = MeshScanner(obj.mesh)
    views = view_sphere(ViewConfig(count=60))  # hemisphere: the underside is never seen
    observable = coverage.set_observable(scanner, views)
    assert 0.5 < observable.mean() < 1.0
    covered = np.zeros(len(coverage.points), dtype=bool)
    previous = (0.0, 0.0)
    for scan in scanner.scan_many(views):
        covered |= coverage.covered_by(scan.hit_points)
        now = coverage.coverage(covered)
        assert now[0] >= previous[0] and now[1] >= previous[1] and now[0] <= now[1]
        previous = now
    assert previous[1] == 1.0 and previous[0] == pytest.approx(observable.mean())


def test_a_sphere_seen_from_all_round_is_fully_observable():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    coverage = SurfaceCoverage(sphere, CoverageConfig(points=2000), np.random.default_rng(0))
    observable = coverage.set_observable(MeshScanner(sphere), view_sphere(ViewConfig(count=40, layout="sphere")))
    assert observable.all()
    one_side = coverage.covered_by(MeshScanner(sphere).scan(Pose.look_at([0.4, 0, 0])).hit_points)
    assert (coverage.points[one_side][:, 0] > 0).all() and 0.2 < one_side.mean() < 0.5
