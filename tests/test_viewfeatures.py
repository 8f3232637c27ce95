"""Per-view features (nbvdata.simulation.viewfeatures): every metric by hand on small grids, the walk against
the information-gain walk, the camera history by hand, and invariance under a quarter turn."""

import math

import numpy as np
import pytest

from nbvdata.core.config import SimConfig
from nbvdata.core.views import ViewSet, look_at_rotations, sphere_positions, view_sphere
from nbvdata.simulation.grid import ray_information
from nbvdata.simulation.viewfeatures import (_SUMS, FEATURES, METRICS, RayBundle, _entropies, _view_sums, area_factor,
                                             camera_history, occupied_distance, view_features, view_sums)

CONFIG = SimConfig()


def H(p):
    return -(p * math.log(p) + (1 - p) * math.log(1 - p))


def _walk(grid: np.ndarray, rays: list[list[tuple[int, int, int]]], shadow: np.ndarray | None = None,
          surface: np.ndarray | None = None) -> dict[str, float]:
    """The sums of one view whose rays pass the given voxels (in order) of ``grid``."""
    n = grid.shape[0]
    flat = grid.astype(np.float32).reshape(-1)
    voxels = np.array([(i * n + j) * n + k for ray in rays for i, j, k in ray], dtype=np.int32)
    offsets = np.concatenate([[0], np.cumsum([len(ray) for ray in rays])]).astype(np.int64)
    sums = np.zeros((1, len(_SUMS)))
    shadow = np.zeros(flat.size) if shadow is None else shadow.reshape(-1)
    surface = np.zeros(flat.size) if surface is None else surface.reshape(-1)
    _view_sums(flat, _entropies(flat), occupied_distance(grid), shadow, surface, offsets, voxels, len(rays), 5, 2, sums)
    return dict(zip(_SUMS, sums[0]))


def test_every_metric_by_hand():
    """Ray 1 passes free, unknown, unknown, occupied; ray 2 free, free, occupied; ray 3 only free."""
    grid = np.full((4, 4, 4), 0.4, dtype=np.float32)
    grid[1, 1, 1] = grid[2, 1, 1] = 0.5
    grid[3, 1, 1] = 0.7
    grid[2, 2, 2] = 0.971
    sums = _walk(grid, [[(0, 1, 1), (1, 1, 1), (2, 1, 1), (3, 1, 1)], [(0, 2, 2), (1, 2, 2), (2, 2, 2), (3, 2, 2)],
                        [(0, 3, 0), (1, 3, 0)]])
    h4, h7, h97, ln2 = H(0.4), H(0.7), H(0.971), math.log(2)
    # visibility along ray 1: 1, 0.6, 0.3, 0.15; along ray 2: 1, 0.6, 0.36
    expected = {
        "rays": 3, "occupied_first": 1, "unknown_first": 1, "unknown_passed": 2, "information": 2 * ln2,
        "occlusion_aware": (h4 + 0.6 * ln2 + 0.3 * ln2 + 0.15 * h7) + (h4 + 0.6 * h4 + 0.36 * h97) + (h4 + 0.6 * h4),
        "unobserved_voxel": 0.6 * ln2 + 0.3 * ln2,
        "rear_side_voxel": 1, "rear_side_entropy": 0.6 * ln2 + 0.3 * ln2,
        "proximity_count": (5 - 1) + (5 - 1),  # (1,1,1) and (2,1,1) are 1 from (2,2,2)
        "near_unknown": 2,
        "entropy_hit": (h4 + 2 * ln2 + h7) + (2 * h4 + h97), "voxels_hit": 4 + 3,
        "area_occupied": 1, "area_occplane": 1, "area_unobserved": 1,  # ray 2 occupied after free; ray 1 occplane
        "depth": 1 + 2, "proximity_shadow": 0, "expected_surface": 0,
    }
    for name, value in expected.items():
        assert sums[name] == pytest.approx(value, rel=1e-7, abs=1e-12), name  # p in float32


def test_features_from_the_sums_by_hand():
    grid = np.full((4, 4, 4), 0.4, dtype=np.float32)
    grid[1, 1, 1] = grid[2, 1, 1] = 0.5
    grid[3, 1, 1] = 0.7
    sums = _walk(grid, [[(0, 1, 1), (1, 1, 1), (2, 1, 1), (3, 1, 1)], [(0, 2, 2), (1, 2, 2)]])
    assert sums["entropy_hit"] / sums["voxels_hit"] == pytest.approx(
        (H(0.4) + 2 * math.log(2) + H(0.7)) / 4)
    # area factor: one ray occplane, one unobserved: shares 0 and 0.5
    assert area_factor(np.array([0.0]), 0.2)[0] == 0
    assert area_factor(np.array([0.5]), 0.8)[0] == pytest.approx(-2 / 0.8 ** 3 * 0.125 + 3 / 0.8 ** 2 * 0.25)
    for desired in (0.2, 0.8):
        x = np.linspace(0, 1, 201)
        f = area_factor(x, desired)
        assert f[0] == pytest.approx(0) and f[-1] == pytest.approx(0, abs=1e-12)
        assert area_factor(np.array([desired]), desired)[0] == pytest.approx(1)
        assert f.max() == pytest.approx(1, abs=1e-3) and (f >= -1e-12).all()


def test_occupied_distance_is_chessboard_and_capped():
    grid = np.full((8, 8, 8), 0.5, dtype=np.float32)
    assert (occupied_distance(grid) == 5).all()  # no occupied voxel: the cap
    grid[4, 4, 4] = 0.7
    d = occupied_distance(grid).reshape(8, 8, 8)
    assert d[4, 4, 4] == 0 and d[5, 5, 5] == 1 and d[6, 4, 2] == 2 and d[0, 0, 0] == 4 and d[4, 4, 0] == 4


def test_the_walk_agrees_with_the_information_gain_walk():
    """``information`` of a bundle equals ``ray_information``'s sum over the same rays (OctoMap's DDA)."""
    rng = np.random.default_rng(3)
    n = 32
    grid = rng.choice(np.array([0.5, 0.4, 0.1192, 0.7, 0.971], dtype=np.float32), size=(n, n, n),
                      p=[0.5, 0.3, 0.1, 0.05, 0.05])
    positions = sphere_positions(40, 0.4, "sphere")
    views = ViewSet(positions, look_at_rotations(positions))
    bundle = RayBundle.build(views, CONFIG.scene_grid, CONFIG.sensor, 6, 5)
    ours = view_sums(grid, bundle)[:, _SUMS.index("information")]
    import dataclasses

    from nbvdata.simulation.sensor import camera_rays
    rays = camera_rays(dataclasses.replace(CONFIG.sensor, width=6, height=5))
    ends = (positions[:, None] + np.matmul(rays[None], views.rotations) * CONFIG.sensor.far).astype(np.float32)
    information = np.zeros(ends.shape[:2])
    first = np.zeros(ends.shape[:2], dtype=np.int8)
    grid_config = CONFIG.scene_grid
    ray_information(positions.astype(np.float32), ends, grid, grid_config.resolution, -(n // 2), 0, n, np.float32(0.5),
                    np.float32(0.5), np.zeros((n, n, n), dtype=np.uint8), information, first)
    assert np.allclose(ours, information.sum(axis=1), rtol=1e-12, atol=1e-12)
    assert ours.max() > 0
    met = view_sums(grid, bundle)
    assert np.array_equal(met[:, _SUMS.index("occupied_first")], (first == 1).sum(axis=1))
    assert np.array_equal(met[:, _SUMS.index("unknown_first")], (first == 2).sum(axis=1))


def test_camera_history_by_hand():
    units = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [-1.0, 0, 0]])
    history = camera_history(units, np.array([[0.4, 0, 0], [0, 0, 0.8]]))  # scans from +x and +z (any radius)
    assert history["nearest_angle"] == pytest.approx([0, math.pi / 2, 0, math.pi / 2])
    assert history["second_angle"] == pytest.approx([math.pi / 2, math.pi / 2, math.pi / 2, math.pi])
    assert history["third_angle"] == pytest.approx([math.pi] * 4)
    assert history["within_30"].tolist() == [1, 0, 1, 0] and history["within_60"].tolist() == [1, 0, 1, 0]
    assert history["mean_cosine"] == pytest.approx([0.5, 0, 0.5, -0.5])
    empty = camera_history(units, np.zeros((0, 3)))
    assert (empty["nearest_angle"] == math.pi).all() and (empty["within_60"] == 0).all()


@pytest.mark.parametrize("layout, count", [("hemisphere", 500), ("sphere", 300), ("tammes-128", 128),
                                           ("pc-nbv-33", 33), ("scvp-32", 32)])
def test_features_on_every_view_set(layout, count):
    views = view_sphere(SimConfig().views.__class__(count=count, layout=layout))
    bundle = RayBundle.build(views, CONFIG.scene_grid, CONFIG.sensor, 4, 3)
    grid = np.full((32, 32, 32), 0.5, dtype=np.float32)
    grid[10:22, 10:22, 10:22] = 0.7
    features = view_features(grid, views.positions[:2], bundle)
    assert features.shape == (count, len(FEATURES)) and features.dtype == np.float32 and np.isfinite(features).all()
    column = dict(zip(FEATURES, features.T))
    assert column["scans"][0] == 2 and column["nearest_angle"][0] == pytest.approx(0, abs=1e-6)
    assert column["grid_occupied"][0] == 12 ** 3 / 32 ** 3
    assert (column["unknown_first"] > 0).all()  # every view of a cube of unknown around the box sees unknown first
    assert set(METRICS.values()) <= set(FEATURES)


def test_a_quarter_turn_leaves_every_feature_unchanged():
    """PC-NBV's 33 views are 4-fold symmetric about z: a quarter turn of grid, views and scans is a
    permutation of the views, and every view's features follow it - but the top view's, whose image
    keeps world +x as its right (``look_at_rotations``), so its rays do not turn with the world.
    An even bundle: no ray lies on the optical axis, where a voxel boundary plane would break the tie."""
    views = view_sphere(SimConfig().views.__class__(count=33, layout="pc-nbv-33"))
    bundle = RayBundle.build(views, CONFIG.scene_grid, CONFIG.sensor, 8, 6)
    rng = np.random.default_rng(0)
    grid = np.full((32, 32, 32), 0.5, dtype=np.float32)
    grid[rng.random((32, 32, 32)) < 0.2] = 0.4
    grid[8:20, 12:25, 5:18] = 0.5
    grid[11:19, 14:22, 6:16] = 0.7
    grid[rng.random((32, 32, 32)) < 0.02] = 0.971
    turned = np.ascontiguousarray(np.rot90(grid, 1, axes=(0, 1)))
    units = views.unit_positions
    rotated = np.stack([-units[:, 1], units[:, 0], units[:, 2]], axis=1)  # (x, y) -> (-y, x)
    permutation = np.argmax(rotated @ units.T, axis=1)  # view v turns into view permutation[v]
    assert np.allclose(units[permutation], rotated, atol=1e-9)
    scanned = views.positions[[3, 17]]
    before = view_features(grid, scanned, bundle)
    after = view_features(turned, np.stack([-scanned[:, 1], scanned[:, 0], scanned[:, 2]], axis=1), bundle)
    turning = np.abs(units[:, 2]) < 1 - 1e-9
    assert turning.sum() == 32
    assert np.allclose(after[permutation][turning], before[turning], rtol=1e-5, atol=1e-6)
    assert before[:, FEATURES.index("unknown_first")].std() > 0  # the views do differ


def test_a_grid_of_another_size_is_refused():
    views = view_sphere(SimConfig().views.__class__(count=33, layout="pc-nbv-33"))
    bundle = RayBundle.build(views, CONFIG.scene_grid, CONFIG.sensor, 2, 2)
    with pytest.raises(ValueError, match="ray bundle was made for"):
        view_features(np.full((16, 16, 16), 0.5, dtype=np.float32), np.zeros((0, 3)), bundle)


def test_the_shadow_and_the_expected_surface_by_hand():
    """rpg's proximity count: unknown voxels k steps behind the first occupied voxel of an earlier
    scan's ray weigh n - k (the fewest steps over the rays); a candidate's ray sums the weights of
    the unknown voxels it passes before its own first occupied voxel. The expected surface: 1 -
    prod(1 - P) over those unknown voxels."""
    from nbvdata.simulation.viewfeatures import _shadow_tags

    n = 4
    grid = np.full((n, n, n), 0.5, dtype=np.float32)
    grid[0, 1, 1] = 0.4
    grid[1, 1, 1] = 0.7  # the scan's hit
    grid[3, 1, 1] = 0.4  # measured free behind: no tag
    flat = grid.reshape(-1)
    index = lambda i, j, k: (i * n + j) * n + k  # noqa: E731
    scan = np.array([index(i, 1, 1) for i in range(4)] + [index(0, 2, 2), index(1, 2, 2)], dtype=np.int32)
    offsets = np.array([0, 4, 6], dtype=np.int64)  # a second ray that meets nothing: tags nothing
    tags = np.full(flat.size, n, dtype=np.int32)
    _shadow_tags(flat, offsets, scan, tags)
    assert tags[index(2, 1, 1)] == 1 and tags[index(3, 1, 1)] == n  # (3,1,1) was measured free: no tag
    assert (np.delete(tags, [index(2, 1, 1)]) == n).all()
    shadow = np.where(flat == 0.5, (n - tags).astype(np.float64), 0.0)
    assert shadow[index(2, 1, 1)] == 3 and shadow[index(3, 1, 1)] == 0
    surface = np.zeros(flat.size)
    surface[index(2, 1, 1)], surface[index(2, 2, 1)] = 0.5, 0.5
    # a candidate from -y: through (2,0,1) unknown, (2,1,1) unknown and tagged, (2,2,1) unknown, (2,3,1) occupied
    grid[2, 3, 1] = 0.971
    sums = _walk(grid, [[(2, 0, 1), (2, 1, 1), (2, 2, 1), (2, 3, 1)]], shadow=shadow, surface=surface)
    assert sums["proximity_shadow"] == 3 and sums["expected_surface"] == pytest.approx(1 - 0.5 * 0.5)


def test_the_shadow_of_a_scan_lies_behind_what_it_hit():
    """A box scanned from one view: its shadow is unknown space on the far side of the faces seen,
    none in front of them, and a candidate looking from behind the box gains it, one from the front
    none."""
    from nbvdata.simulation.scene import Scene
    from nbvdata.simulation.shapes import builtin_object
    from nbvdata.simulation.viewfeatures import shadow_weights

    obj = builtin_object("step_block", CONFIG.mesh)
    scene = Scene.build(obj, CONFIG, np.random.default_rng(0), threads=1)
    grid = scene.new_grid()
    views = scene.views
    front = int(np.argmax(views.unit_positions @ np.array([1.0, 0.0, 0.3])))
    scene.integrate(grid, scene.scanner.scan(views[front]))
    probabilities = grid.probabilities()
    bundle = RayBundle.build(views, CONFIG.scene_grid, CONFIG.sensor, 16, 12)
    weights = shadow_weights(probabilities, views.positions[[front]], bundle).reshape(probabilities.shape)
    assert (weights[probabilities != 0.5] == 0).all() and (weights > 0).sum() > 100
    centres = np.stack(np.meshgrid(*[np.arange(32) - 15.5] * 3, indexing="ij"), axis=-1)
    toward = views.unit_positions[front]
    assert (centres[weights > 0] @ toward).mean() < (centres[probabilities > 0.5] @ toward).mean()
    features = view_features(probabilities, views.positions[[front]], bundle)
    column = features[:, FEATURES.index("proximity_shadow")]
    behind = int(np.argmin(views.unit_positions @ toward))
    assert column[behind] > 0 and column[front] == 0
