import math

import numpy as np
import pytest
import trimesh
from conftest import MESHES, need

from nbvdata.core.config import GridConfig, MeshConfig, SensorConfig, SimConfig, ViewConfig
from nbvdata.core.views import Pose, view_sphere
from nbvdata.simulation.grid import OccupancyGrid
from nbvdata.simulation.mesh import load_mesh
from nbvdata.simulation.sensor import MeshScanner, Scan
from nbvdata.simulation.shapes import builtin_object

FAR = SensorConfig().far


def octomap_probabilities(scans, config: GridConfig, far: float) -> np.ndarray:
    """The same scans through OctoMap's own insertPointCloud, read back voxel by voxel."""
    pyoctomap = pytest.importorskip("pyoctomap", reason="pip install pyoctomap (a test dependency)")
    grid = OccupancyGrid(config)
    tree = pyoctomap.OcTree(grid.resolution)
    for setter, value in [(tree.setProbHit, config.prob_hit), (tree.setProbMiss, config.prob_miss),
                          (tree.setClampingThresMin, config.clamp_min), (tree.setClampingThresMax, config.clamp_max)]:
        setter(value)
    for scan in scans:
        tree.insertPointCloud(scan.points.astype(np.float64), scan.origin.astype(np.float64), max_range=far)
    centres = grid.voxel_centres().reshape(-1, 3)
    result = np.full(len(centres), 0.5, dtype=np.float32)
    for index, centre in enumerate(centres):
        node = tree.search(centre)
        if node is not None:
            result[index] = node.getOccupancy()
    return result.reshape(grid.log_odds.shape)


def _scans(obj, count, seed, sensor=SensorConfig()):
    rng = np.random.default_rng(seed)
    views = view_sphere(ViewConfig(count=500, layout="sphere"))
    picks = rng.choice(len(views), count, replace=False)
    return MeshScanner(obj.mesh, sensor).scan_many([views[int(i)] for i in picks], rng)


def _assert_same_as_octomap(scans, config=None):
    config = config or SimConfig().scene_grid
    grid = OccupancyGrid(config)
    for scan in scans:
        grid.integrate(scan, FAR)
    ours = grid.probabilities()
    reference = octomap_probabilities(scans, config, FAR)
    differ = np.argwhere(ours != reference)
    assert len(differ) == 0, f"{len(differ)} voxels differ from OctoMap, first {differ[:5].tolist()}"
    counts = grid.counts()
    assert counts["occupied"] > 100 and counts["unknown"] > 0 and counts["free"] > 1000
    return grid


@pytest.mark.parametrize("name", [
    "test/bunny_hr__odedstein.obj", "test/teapot__alecjacobson.obj", "test/chair__trimesh.obj",
    "train/drill__ycb_urdfmodels.obj", "train/desk_lamp__sh3d_blendswap_cc0.ply",
])
def test_identical_to_octomap_on_shared_meshes(name):
    obj = load_mesh(need(MESHES / name))
    _assert_same_as_octomap(_scans(obj, 4, seed=len(name)))


@pytest.mark.parametrize("shape", ["mug", "step_block", "ring"])
def test_identical_to_octomap_on_builtin_shapes(shape):
    _assert_same_as_octomap(_scans(builtin_object(shape), 4, seed=3))


def test_identical_to_octomap_with_noise_other_sizes_and_near_sensor():
    obj = builtin_object("table_lamp", MeshConfig(object_size=0.3))
    scans = _scans(obj, 3, seed=5, sensor=SensorConfig(noise_std=0.003, width=120, height=90))
    # A view inside the grid cube and grid settings other than the defaults.
    scans.append(MeshScanner(obj.mesh, SensorConfig(width=60, height=40)).scan(Pose.look_at([0.0, 0.15, 0.2])))
    _assert_same_as_octomap(scans, GridConfig(size=24, extent=0.36, prob_hit=0.8, clamp_max=0.95))


# 1 cm voxels in a fixed 0.32 m cube, as the hand-made cases below assume (and big enough for a 0.2 m
# box; the default cube is fitted to a 0.136 m object).
CM_GRID = GridConfig(extent=0.32)


@pytest.fixture(scope="module")
def box_scan():
    scanner = MeshScanner(trimesh.creation.box((0.2, 0.2, 0.2)), SensorConfig(width=88, height=72))
    return scanner.scan(Pose.look_at([0.4, 0.0, 0.0]))


def test_box_seen_from_plus_x_is_occupied_only_on_its_plus_x_side(box_scan):
    grid = OccupancyGrid(CM_GRID)
    grid.integrate(box_scan, FAR)
    p = grid.probabilities()
    centres = grid.voxel_centres()
    occupied = centres[p > 0.5]
    assert len(occupied) > 100
    assert occupied[:, 0].min() >= 0.09 and occupied[:, 0].max() <= 0.11
    inside_box = np.all(np.abs(centres) < 0.085, axis=-1)
    assert (p[inside_box] == 0.5).all(), "the inside of the box was never observed"
    in_front = (centres[..., 0] > 0.12) & (np.abs(centres[..., 1]) < 0.05) & (np.abs(centres[..., 2]) < 0.05)
    assert (p[in_front] < 0.5).all(), "space between sensor and face is free"


def test_unknown_is_exactly_one_half_and_counts_add_up(box_scan):
    grid = OccupancyGrid(CM_GRID)
    assert (grid.probabilities() == np.float32(0.5)).all()
    assert grid.counts() == {"occupied": 0, "free": 0, "unknown": 32 ** 3}
    grid.integrate(box_scan, FAR)
    counts = grid.counts()
    assert sum(counts.values()) == 32 ** 3
    assert counts["unknown"] == int((grid.probabilities() == 0.5).sum())


def test_repeated_scans_raise_confidence_until_the_clamps(box_scan):
    grid = OccupancyGrid(CM_GRID)
    grid.integrate(box_scan, FAR)
    once = grid.probabilities()
    occupied, free = once > 0.5, once < 0.5
    np.testing.assert_allclose(once[occupied], 0.7, rtol=1e-6)
    np.testing.assert_allclose(once[free], 0.4, rtol=1e-6)
    grid.integrate(box_scan, FAR)
    twice = grid.probabilities()
    assert (twice[occupied] > once[occupied]).all() and (twice[free] < once[free]).all()
    np.testing.assert_allclose(twice[free], 0.16 / 0.52, rtol=1e-6)  # 0.307692: two misses
    for _ in range(30):
        grid.integrate(box_scan, FAR)
    clamped = grid.probabilities()
    np.testing.assert_allclose(clamped[occupied], 0.971, rtol=1e-6)
    np.testing.assert_allclose(clamped[free], 0.1192, rtol=1e-5)


def test_within_one_scan_a_hit_wins_over_a_miss():
    origin = np.array([0.4, 0.005, 0.005], dtype=np.float32)
    # Ray A ends in voxel (20, 16, 16) (x in [0.04, 0.05)); ray B passes through it to x = -0.095.
    points = np.array([[0.045, 0.005, 0.005], [-0.095, 0.005, 0.005]], dtype=np.float32)
    grid = OccupancyGrid(CM_GRID)
    grid.integrate(Scan(origin, points, np.array([True, True])), FAR)
    p = grid.probabilities()
    assert p[20, 16, 16] == pytest.approx(0.7, rel=1e-6)
    assert p[21, 16, 16] == pytest.approx(0.4, rel=1e-6)
    assert p[6, 16, 16] == pytest.approx(0.7, rel=1e-6) and p[5, 16, 16] == 0.5
    assert p[7, 16, 16] == pytest.approx(0.4, rel=1e-6)


def test_rays_without_return_carve_free_space_to_the_far_range():
    origin = np.array([0.4, 0.005, 0.005], dtype=np.float32)
    beyond = np.array([[-1.6, 0.005, 0.005]], dtype=np.float32)  # 2 m away: no return
    for far, last_free in [(1.0, 0), (0.545, 2)]:  # 0.545 m ends in voxel 1, left unmarked
        grid = OccupancyGrid(CM_GRID)
        grid.integrate(Scan(origin, beyond, np.array([False])), far)
        p = grid.probabilities()[:, 16, 16]
        assert (p[last_free:] == np.float32(0.4)).all() and (p[:last_free] == 0.5).all()
        assert grid.counts()["occupied"] == 0


def test_identical_to_octomap_for_rays_grazing_the_grid_almost_parallel_to_a_face():
    """Rays that pass beside the grid, or just inside it, nearly parallel to a face (the case the
    walk rules out by geometry before stepping): each at an offset from the face's plane
    between -1 mm and +1 mm, down to 1e-9 m, and tilted by 1e-3 to 1e-7 rad."""
    grid = OccupancyGrid()
    top = (grid.first_key + grid.size) * grid.resolution  # the z of the grid's top face
    origin = np.array([0.3, 0.02, top], dtype=np.float32)
    points = []
    for offset in (-1e-3, -1e-5, -1e-7, -1e-9, 0.0, 1e-9, 1e-7, 1e-5, 1e-3):
        for tilt in (1e-3, 1e-5, 1e-7, -1e-7, -1e-5):
            for y in (-0.05, 0.0, 0.03):
                end = np.array([-1.7, y, top + offset + 2.0 * tilt])
                points.append(end)
    points = np.array(points, dtype=np.float32)
    scan = Scan(origin, points, np.zeros(len(points), dtype=bool))
    ours = OccupancyGrid()
    ours.integrate(scan, FAR)
    reference = octomap_probabilities([scan], ours.config, FAR)
    assert np.array_equal(ours.probabilities(), reference)
    assert ours.counts()["free"] > 50


def test_the_information_gain_walk_sums_the_unknown_voxels_before_the_first_occupied_one():
    """One ray along x through the middle row of an 8^3 grid of side 1 m: free, three unknown
    voxels, an occupied one, then unknown again: the walk stops at the occupied voxel, so it sums
    the entropy of the three (3 ln 2) and says that the first non-free voxel it met was unknown;
    a box that leaves out voxels 2-3 counts only voxel 4, and with an occupied voxel first it says 1."""
    from nbvdata.simulation.grid import ray_information

    n = 8
    grid = np.full((n, n, n), 0.3, dtype=np.float32)
    grid[2:5, 4, 4] = 0.5
    grid[5, 4, 4] = 0.7
    grid[6, 4, 4] = 0.5
    origins = np.array([[-0.6, 0.0625, 0.0625]], dtype=np.float32)
    ends = np.array([[[0.6, 0.0625, 0.0625]]], dtype=np.float32)

    def walk(probabilities, box=(0, n)):
        information, first = np.zeros((1, 1)), np.zeros((1, 1), dtype=np.int8)
        ray_information(origins, ends, probabilities, 1.0 / n, -(n // 2), box[0], box[1], 0.45, 0.55,
                        np.zeros((n, n, n), dtype=np.bool_), information, first)
        return information[0, 0], int(first[0, 0])

    assert walk(grid) == pytest.approx((3 * math.log(2), 2))
    assert walk(grid, box=(4, 8))[0] == pytest.approx(math.log(2))
    occupied_first = grid.copy()
    occupied_first[1, 4, 4] = 0.9
    assert walk(occupied_first) == (0.0, 1)
