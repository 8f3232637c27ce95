"""Partial point clouds (state.points): exact farthest-point sampling, clouds on the surface and
made of the scanned points, the same for any workers and backend, PC-NBV's view layout and the
export its loader reads."""

from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import MESHES, SHARED, need

from nbvdata.cli import main
from nbvdata.core.cloud import ScannedCloud, farthest_points, farthest_points_reference, reduce_cloud
from nbvdata.core.config import (FIXED_LAYOUT_COUNTS, ConfigError, MeshConfig, SensorConfig, SimConfig, ViewConfig,
                                 load_config)
from nbvdata.core.views import FIXED_LAYOUTS, Y_UP_TO_Z_UP, pc_nbv_33, view_sphere
from nbvdata.datasets.generate import generate
from nbvdata.schema.shards import Shard, view_state
from nbvdata.simulation._open3d import open3d as o3d
from nbvdata.simulation.episode import Reconstruction, ViewCache, scene_rng
from nbvdata.simulation.mesh import load_mesh
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.sensor import EDGE_TOLERANCE, MeshScanner
from nbvdata.simulation.shapes import builtin_object
from nbvdata.simulation.sources import builtin_sources

SMOKE = Path(__file__).resolve().parents[1] / "configs" / "smoke.yaml"
POINTS = 128


def _config(*overrides: str) -> SimConfig:
    return load_config(SimConfig, SMOKE, list(overrides))


def _surface_distance(mesh, points: np.ndarray) -> np.ndarray:
    """(M,) unsigned distance of each point to the mesh's surface (open3d, float32)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))).numpy()


# ---------------------------------------------------------------------------------------------
# Farthest-point sampling


@pytest.mark.parametrize("kind", ["uniform", "surface", "lattice", "duplicates", "line"])
@pytest.mark.parametrize("size", [1, 7, 300, 5000])
def test_fps_is_the_plain_loops_choice_index_for_index(rng, kind, size):
    if kind == "uniform":
        points = rng.random((size, 3))
    elif kind == "surface":  # a sphere's shell, as scans are
        points = rng.normal(size=(size, 3))
        points /= np.linalg.norm(points, axis=1, keepdims=True)
    elif kind == "lattice":  # many exactly equal distances: ties must go to the lowest index
        points = rng.integers(0, 4, (size, 3)).astype(np.float64)
    elif kind == "duplicates":
        points = np.repeat(rng.random((size // 3 + 1, 3)), 3, axis=0)[:size]
    else:
        points = np.zeros((size, 3))
        points[:, 0] = rng.random(size)
    points = (points * 0.1).astype(np.float32)
    for count in sorted({1, min(size, 2), min(size, 64), size}):
        chosen = farthest_points(points, count)
        assert np.array_equal(chosen, farthest_points_reference(points, count)), count
        assert chosen[0] == 0


def test_fps_of_scanned_clouds_is_the_plain_loops(rng):
    obj = builtin_object("mug", SimConfig().mesh)
    scene = Scene.build(obj, _config("sensor.width=88", "sensor.height=72"), scene_rng(0, obj.mesh_id))
    cloud = ScannedCloud()
    for number, view in enumerate(rng.choice(len(scene.views), 6, replace=False)):
        cloud.add(scene.scanner.scan(scene.views[int(view)]).cloud_points)
        if number == 2:
            cloud.add(np.zeros((0, 3), dtype=np.float32))  # a scan that saw nothing
    points = cloud.points()
    assert len(points) > 2000
    reference = farthest_points_reference(points, 1024)
    assert np.array_equal(farthest_points(points, 1024), reference)
    reduced, count = cloud.reduce(1024)
    assert count == len(points) and np.array_equal(reduced, points[reference])


def test_fps_spreads_the_points():
    """Farthest-point sampling of a dense line picks its two ends first, then the middle."""
    line = np.zeros((1001, 3), dtype=np.float32)
    line[:, 0] = np.linspace(0, 1, 1001)
    assert farthest_points(line[::-1].copy(), 3).tolist() == [0, 1000, 500]


def test_reduce_cloud_pads_by_repeating_and_counts(rng):
    points = rng.random((5, 3)).astype(np.float32)
    reduced, count = reduce_cloud(points, 12)
    assert count == 5 and reduced.shape == (12, 3) and reduced.dtype == np.float32
    assert np.array_equal(reduced, points[np.arange(12) % 5])
    reduced, count = reduce_cloud(points, 5)
    assert count == 5 and np.array_equal(reduced, points)
    reduced, count = reduce_cloud(points, 3)
    assert count == 5 and np.array_equal(reduced, points[farthest_points_reference(points, 3)])
    reduced, count = reduce_cloud(np.zeros((0, 3)), 4)
    assert count == 0 and not reduced.any() and reduced.shape == (4, 3)


# ---------------------------------------------------------------------------------------------
# Clouds in the shards


@pytest.fixture(scope="module")
def sources():
    return builtin_sources()[:2]


@pytest.fixture(scope="module")
def clouds(tmp_path_factory, sources):
    """One worker, a run per shard: the shards the other ways of running must give."""
    out = tmp_path_factory.mktemp("clouds")
    report = generate(sources, out, _config(f"state.points={POINTS}", "generate.workers=1",
                                            "generate.runs_per_shard=1"))
    assert not report.failures and report.samples > 0
    return out


def _arrays(folder: Path, names=("points", "points_count", "reference_points", "grids", "gains")) -> dict:
    arrays = {}
    for path in sorted(folder.glob("*.h5")):
        with Shard(path) as shard:
            arrays[path.name] = {name: shard[name] for name in names}
    return arrays


@pytest.mark.parametrize("backend", ["loky", "threading"])
def test_two_workers_give_the_same_clouds_as_one(tmp_path, sources, clouds, backend):
    generate(sources, tmp_path, _config(f"state.points={POINTS}", "generate.workers=2", "generate.runs_per_shard=1",
                                        f"generate.backend={backend}"))
    one, two = _arrays(clouds), _arrays(tmp_path)
    assert one.keys() == two.keys() and len(one) == 6
    for name in one:
        for dataset in one[name]:
            assert np.array_equal(one[name][dataset], two[name][dataset]), (name, dataset)


def test_clouds_are_the_scanned_points_on_the_surface(clouds, sources):
    """Noise-free: every stored point is one of the hits of the views the run scanned by that
    state (points_count of them in all, in scan order, reduced by FPS), on the mesh's surface
    within 1e-6 m; the reference points are the scene's."""
    config = _config(f"state.points={POINTS}")
    for source in sources:
        obj = source.load(config.mesh)
        scene = Scene.build(obj, config, scene_rng(0, source.mesh_id))
        hits = {}
        for path in sorted(clouds.glob(f"{source.stem}-*.h5")):
            with Shard(path) as shard:
                assert np.array_equal(shard["step"], np.arange(len(shard)) + 1)  # one run, in scan order
                points, counts, order = shard["points"], shard["points_count"], shard["last_view"]
                assert np.array_equal(shard["reference_points"], scene.coverage.points.astype(np.float32))
                for i in range(len(shard)):
                    scanned = []
                    for view in order[:i + 1]:
                        if view not in hits:
                            hits[view] = scene.scanner.scan(scene.views[int(view)]).cloud_points
                        scanned.append(hits[view])
                    scanned = np.concatenate(scanned)
                    assert counts[i] == len(scanned)
                    rows = {row.tobytes() for row in scanned}
                    assert all(row.tobytes() in rows for row in points[i])  # a subset of the scanned points
                    expected, _ = reduce_cloud(scanned, POINTS)
                    assert np.array_equal(points[i], expected)
                distance = _surface_distance(obj.mesh, points.reshape(-1, 3))
                assert distance.max() < 1e-6


def _exact_distances(points: np.ndarray, mesh) -> np.ndarray:
    """(M,) float64 distance of each point to the nearest triangle of ``mesh`` (its float32
    vertices), by brute force over every triangle (Ericson's closest point on a triangle)."""
    v = np.asarray(mesh.vertices, dtype=np.float32).astype(np.float64)
    a, b, c = (v[np.asarray(mesh.faces)[:, k]] for k in range(3))
    ab, ac = b - a, c - a
    out = np.empty(len(points))
    for i, p in enumerate(np.asarray(points, dtype=np.float64)):
        ap, bp, cp = p - a, p - b, p - c
        d1, d2, d3, d4, d5, d6 = ((x * y).sum(1) for x, y in ((ab, ap), (ac, ap), (ab, bp), (ac, bp), (ab, cp),
                                                                (ac, cp)))
        va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
        with np.errstate(all="ignore"):
            denom = va + vb + vc
            q = a + ab * (vb / denom)[:, None] + ac * (vc / denom)[:, None]  # inside
            for mask, point in (((va <= 0) & (d4 >= d3) & (d5 >= d6), b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None]),
                                ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * (d2 / (d2 - d6))[:, None]),
                                ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * (d1 / (d1 - d3))[:, None]),
                                ((d6 >= 0) & (d5 <= d6), c), ((d3 >= 0) & (d4 <= d3), b), ((d1 <= 0) & (d2 <= 0), a)):
                q = np.where(mask[:, None], point, q)
        distance = np.linalg.norm(q - p, axis=1)
        out[i] = np.nanmin(distance)
    return out


def _many_body_open_mesh():
    """Three bodies, none closed: a cone of 1.4-degree slivers without its base, a tube without
    caps, and a mug's faces with every tenth one removed."""
    cone = trimesh.creation.cone(radius=0.04, height=0.1, sections=256)
    cone.update_faces(cone.face_normals[:, 2] > -0.5)
    cone.apply_translation([-0.05, 0.0, -0.04])
    tube = trimesh.creation.cylinder(radius=0.02, height=0.12, sections=64)
    tube.update_faces(np.abs(tube.face_normals[:, 2]) < 0.5)
    tube.apply_translation([0.06, 0.0, 0.0])
    mug = builtin_object("mug").mesh.copy()
    mug.update_faces(np.arange(len(mug.faces)) % 10 != 0)
    return trimesh.util.concatenate([cone, tube, mug])


def _bound_holds(mesh, views) -> tuple[int, float]:
    """(points, largest exact distance) of the noise-free cloud points of scans from ``views``:
    open3d's float32 distance picks the candidates (it errs by a few um on slivers), the exact
    float64 distance decides."""
    scanner = MeshScanner(mesh, SensorConfig(width=88, height=72), threads=1)
    points = np.concatenate([scan.cloud_points for scan in scanner.scan_many(views)])
    near = _surface_distance(mesh, points)
    doubtful = points[near > 5e-7]
    return len(points), float(_exact_distances(doubtful, mesh).max()) if len(doubtful) else float(near.max())


def test_clouds_of_a_many_body_open_mesh_lie_within_the_edge_tolerance_of_the_surface():
    """The true bound of a noise-free cloud: each point within EDGE_TOLERANCE of the triangle
    whose plane it lies on, hence of the surface (plus float32 rounding)."""
    count, worst = _bound_holds(_many_body_open_mesh(), view_sphere(ViewConfig(count=60)))
    assert count > 50_000 and worst <= EDGE_TOLERANCE + 1e-7


def test_clouds_of_a_shared_many_body_open_mesh_keep_the_bound():
    """A Sweet Home 3D camera (8 bodies, not watertight, many slivers)."""
    path = need(MESHES / "train" / "camera__sh3d_scopia.ply")
    obj = load_mesh(path, MeshConfig())
    count, worst = _bound_holds(obj.mesh, view_sphere(ViewConfig(count=60)))
    assert count > 20_000 and worst <= EDGE_TOLERANCE + 1e-7


def test_noisy_clouds_lie_on_the_surface_within_the_noise_and_hold_every_hit(tmp_path, sources):
    noise = 0.002
    config = _config(f"state.points={POINTS}", f"sensor.noise_std={noise}", "episode.runs_per_mesh=1",
                     "generate.workers=1")
    generate(sources[:1], tmp_path, config)
    obj = sources[0].load(config.mesh)
    scene = Scene.build(obj, config, scene_rng(0, sources[0].mesh_id))
    (path,) = tmp_path.glob("*.h5")
    with Shard(path) as shard:
        points, counts, seed, order = shard["points"], shard["points_count"], int(shard["seed"][0]), shard["last_view"]
        assert np.array_equal(shard["step"], np.arange(len(shard)) + 1)
    # the run's scans cast again with its noise stream, in its order: each state's points are
    # some of the hits scanned by then, all of them counted
    stream = np.random.default_rng(seed)
    scanned = []
    for i, view in enumerate(order):
        scanned.append(scene.scanner.scan(scene.views[int(view)], stream).cloud_points)
        hits = np.concatenate(scanned)
        assert counts[i] == len(hits)
        rows = {row.tobytes() for row in hits}
        assert all(row.tobytes() in rows for row in points[i])
    distance = _surface_distance(obj.mesh, points.reshape(-1, 3))
    assert distance.max() < 6 * noise and distance.max() > 1e-4  # the noise is in the points


def test_cached_and_live_scans_give_the_same_clouds(rng):
    """The generator's cached views and a closed loop's live scans build the same cloud."""
    config = _config(f"state.points={POINTS}")
    obj = builtin_object("pill", config.mesh)
    scene = Scene.build(obj, config, scene_rng(0, obj.mesh_id))
    cached = Reconstruction(scene, ViewCache(scene, points=True), rng, points=True)
    live = Reconstruction(scene, None, rng, points=True)
    for view in (3, 17, 40):
        cached.scan(view)
        live.scan(view)
        assert np.array_equal(cached.cloud.points(), live.cloud.points())
    assert np.array_equal(cached.cloud.reduce(POINTS)[0], live.cloud.reduce(POINTS)[0])


def test_inspect_and_show_report_the_clouds(clouds, tmp_path, capsys):
    assert main(["inspect", str(clouds)]) == 0
    assert f"point clouds: {POINTS} points per state" in capsys.readouterr().out
    png = tmp_path / "a.png"
    assert main(["show", str(sorted(clouds.glob("*.h5"))[0]), "--index", "1", "--out", str(png)]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("value, message", [
    ("-1", "state.points=-1: must be an integer >= 0"),
    ("1.5", "state.points=1.5: must be an integer"),
    ("many", "state.points='many': must be an integer"),
])
def test_bad_point_counts_are_one_line_and_exit_2(tmp_path, capsys, value, message):
    assert main(["generate", "--out", str(tmp_path / "out"), "--config", str(SMOKE), "--set",
                 f"state.points={value}"]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_the_default_records_no_state_section():
    assert "state" not in SimConfig().dataset_dict()
    assert SimConfig(state=load_config(SimConfig, overrides=["state.points=8"]).state).dataset_dict()["state"] == \
        {"points": 8}


# ---------------------------------------------------------------------------------------------
# PC-NBV's view layout


def test_pc_nbv_views_are_the_files_directions_turned_to_z_up():
    table = np.loadtxt(need(SHARED / "anchors" / "pc-nbv_viewspace_33.txt"))
    assert np.abs(pc_nbv_33() - table @ Y_UP_TO_Z_UP.T).max() < 1e-15
    assert np.allclose(Y_UP_TO_Z_UP @ Y_UP_TO_Z_UP.T, np.eye(3)) and np.isclose(np.linalg.det(Y_UP_TO_Z_UP), 1.0)
    assert np.allclose(Y_UP_TO_Z_UP @ [0, 1, 0], [0, 0, 1])  # their up is our up


def test_pc_nbv_layout_scales_to_the_radius_and_needs_33_views():
    views = view_sphere(ViewConfig(radius=0.7, count=33, layout="pc-nbv-33"))
    assert np.allclose(views.positions, 0.7 * pc_nbv_33())
    assert np.allclose(views.rotations[:, 2], -pc_nbv_33())  # each looks at the centre
    assert (views.positions[:, 2] < 0).sum() == 8  # a ring below the equator
    with pytest.raises(ConfigError, match="views.layout=pc-nbv-33 has 33 views: set views.count=33"):
        load_config(SimConfig, overrides=["views.layout=pc-nbv-33"])
    assert {name: len(layout()) for name, layout in FIXED_LAYOUTS.items()} == FIXED_LAYOUT_COUNTS


def test_generation_on_the_pc_nbv_layout_records_it(tmp_path, sources):
    config = _config("views.layout=pc-nbv-33", "views.count=33", "state.points=64", "episode.runs_per_mesh=2",
                     "generate.workers=1")
    report = generate(sources[:1], tmp_path, config)
    assert not report.failures and report.samples > 0
    with Shard(next(tmp_path.glob("*.h5"))) as shard:
        assert shard.info.config["views"]["layout"] == "pc-nbv-33"
        assert np.allclose(shard["view_positions"], 0.4 * pc_nbv_33())


# ---------------------------------------------------------------------------------------------
# Export in PC-NBV's layout


def _read_like_pc_nbv(folder: Path, model: str, runs: range, scans: int):
    """What PC-NBV's LMDB writer yields (lmdb_write_shapenet.py: np.load of the three files per
    run and scan), with the ground truth read from gt.xyz as their generator saved it."""
    gt = np.loadtxt(folder / model / "gt.xyz")
    for ex_index in runs:
        for scan_index in range(scans):
            base = folder / model / str(ex_index)
            view_state = np.load(base / f"{scan_index}_viewstate.npy")
            cloud = np.load(base / f"{scan_index}_acc_pc.npy")
            target_value = np.load(base / f"{scan_index}_target_value.npy")
            yield model, cloud, gt, view_state, target_value


def test_export_reads_back_as_pc_nbvs_loader_reads_it(clouds, tmp_path, capsys):
    out = tmp_path / "pcnbv"
    assert main(["export", str(clouds), "--format", "pc-nbv", "--out", str(out)]) == 0
    assert "exported" in capsys.readouterr().out
    views = np.loadtxt(out / "viewspace.txt")
    for path in sorted(clouds.glob("*.h5")):
        with Shard(path) as shard:
            model = path.name.rsplit("-runs", 1)[0]
            assert np.allclose(views, shard["view_positions"] / 0.4, atol=1e-15)
            taken = view_state(shard["run"], shard["step"], shard["last_view"], len(views))
            assert (shard["run"] == shard["run"][0]).all() and np.array_equal(shard["step"], np.arange(len(shard)) + 1)
            run = int(shard["run"][0])
            rows = list(_read_like_pc_nbv(out, model, range(run, run + 1), len(shard)))
            for i, (_, cloud, gt, state, target) in enumerate(rows):
                assert state.shape == (len(views),) and state.dtype == np.int64
                assert np.array_equal(state, taken[i].astype(np.int64))
                assert cloud.ndim == 2 and cloud.shape[1] == 3 and cloud.dtype == np.float64
                count = min(int(shard["points_count"][i]), POINTS)
                assert np.array_equal(cloud, shard["points"][i][:count].astype(np.float64))
                assert target.shape == (len(views), 1) and target.dtype == np.float64
                assert np.array_equal(target[:, 0], shard["gains"][i].astype(np.float64))
                assert np.array_equal(gt, shard["reference_points"].astype(np.float64))


def test_export_refuses_shards_without_clouds_an_unknown_format_and_a_used_folder(tmp_path, sources, clouds, capsys):
    plain = tmp_path / "plain"
    generate(sources[:1], plain, _config("episode.runs_per_mesh=1", "generate.workers=1"))
    cases = [([str(plain), "--format", "pc-nbv", "--out", str(tmp_path / "a")], "state.points=1024"),
             ([str(clouds), "--format", "pcnbv", "--out", str(tmp_path / "b")], "unknown format; choose one of pc-nbv"),
             ([str(clouds), "--format", "pc-nbv", "--out", str(plain)], "not an empty folder")]
    for argv, message in cases:
        assert main(["export", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "a").exists() and not (tmp_path / "a.partial").exists() and not (tmp_path / "b").exists()
