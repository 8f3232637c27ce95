"""nbvtrain plan: a robot's scans (cloud files + poses) or OctoMap in its world frame give exactly
the simulator's grid and ``nbvtrain predict``'s pose on it, moved with the scene; bad input is
one line and exit 2."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from scipy.spatial.transform import Rotation

from nbvdata.core.config import SimConfig, load_config
from nbvdata.core.views import Pose, scanned_views, view_sphere
from nbvdata.simulation.grid import OccupancyGrid
from nbvdata.simulation.sensor import MeshScanner
from nbvdata.simulation.shapes import builtin_object
from nbvtrain.cli import main
from nbvtrain.networks.config import TrainConfig
from nbvtrain.networks.models import build_model
from nbvtrain.networks.predict import NBVPrediction
from nbvtrain.networks.train import save_training_state
from nbvtrain.robot.plan import ObjectFrame, PlanError, draw_plan, plan, up_rotation
from nbvtrain.robot.sensordata import SensorDataError, read_cloud

ROOT = Path(__file__).resolve().parents[1]
FIXED_CUBE = ROOT / "configs" / "scene-fixed-cube.yaml"
VIEWS = (7, 180, 333, 460)  # candidate views of the default 500: around the object, low and high
FORMATS = (".ply", ".pcd", ".xyz", ".npy")


def _checkpoint(path: Path, model: str = "nbvnet-3-3") -> Path:
    torch.manual_seed(0)
    net = build_model(model)
    save_training_state(path, net, torch.optim.Adam(net.parameters()), TrainConfig(model=model), [], 0, 0.4)
    return path


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    return _checkpoint(tmp_path_factory.mktemp("ckpt") / "best.pt")


def _simulate(config: SimConfig, shape: str = "mug"):
    """Scans of a built-in shape from VIEWS (object frame) and the simulator's grid of them."""
    obj = builtin_object(shape, config.mesh)
    views = view_sphere(config.views)
    poses = [views[i] for i in VIEWS]
    scans = MeshScanner(obj.mesh, config.sensor, threads=1).scan_many(poses)
    grid = OccupancyGrid(config.scene_grid)
    for scan in scans:
        grid.integrate(scan, config.sensor.far)
    return scans, poses, grid.probabilities()


@pytest.fixture(scope="module")
def scene():
    return _simulate(SimConfig())


def _write_cloud(path: Path, points: np.ndarray) -> None:
    """points (N, 3) float32 or float64, written so that reading gives exactly the same values."""
    suffix = path.suffix
    if suffix == ".npy":
        np.save(path, points)
    elif suffix == ".xyz":
        np.savetxt(path, points.astype(np.float64), fmt="%.17g")
    elif suffix == ".ply":
        kind, dtype = ("float", "<f4") if points.dtype == np.float32 else ("double", "<f8")
        header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(points)}\nproperty {kind} x\n"
                  f"property {kind} y\nproperty {kind} z\nend_header\n")
        path.write_bytes(header.encode() + points.astype(dtype).tobytes())
    elif suffix == ".pcd":
        size, dtype = (4, "<f4") if points.dtype == np.float32 else (8, "<f8")
        header = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z _\nSIZE {size} {size} {size} 1\nTYPE F F F U\n"
                  f"COUNT 1 1 1 1\nWIDTH {len(points)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(points)}\n"
                  "DATA binary\n")
        padded = np.zeros(len(points), dtype=[("xyz", dtype, 3), ("_", "u1")])
        padded["xyz"] = points
        path.write_bytes(header.encode() + padded.tobytes())


def _write_scans(folder: Path, scans, poses, move=None, dtype=np.float32) -> Path:
    """A scans file of the simulator's scans, each cloud in another format, poses alternately as a
    4x4 matrix and as position + quaternion. ``move`` (4, 4): a rigid motion of the whole scene,
    or one with a uniform scale (a larger scene: sensors move, their rotations do not scale)."""
    folder.mkdir(parents=True, exist_ok=True)
    move = np.eye(4) if move is None else move
    scale = np.linalg.norm(move[:3, 0])
    entries = []
    for number, (scan, pose) in enumerate(zip(scans, poses)):
        matrix = np.eye(4)
        matrix[:3, :3] = move[:3, :3] / scale @ pose.rotation.T
        matrix[:3, 3] = move[:3, :3] @ scan.origin + move[:3, 3]  # the float32 origin the simulator's rays start at
        points = scan.points.astype(np.float64) @ move[:3, :3].T + move[:3, 3]
        cloud = f"cloud{number}{FORMATS[number % len(FORMATS)]}"
        _write_cloud(folder / cloud, points.astype(dtype))
        if number % 2:
            quaternion = Rotation.from_matrix(matrix[:3, :3]).as_quat()
            entries.append({"cloud": cloud, "position": matrix[:3, 3].tolist(), "quaternion_xyzw": quaternion.tolist()})
        else:
            entries.append({"cloud": cloud, "pose": matrix.tolist()})
    path = folder / "scans.yaml"
    path.write_text(yaml.safe_dump(entries))
    return path


def _plan(capsys, *argv) -> dict:
    assert main(["plan", *map(str, argv)]) == 0
    return json.loads(capsys.readouterr().out)


def _one_line_error(capsys, *expected: str) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith("nbvtrain plan: error: ") and all(text in err for text in expected), err
    return err


def test_cloud_formats_read_back_exactly(tmp_path, rng):
    points = rng.normal(size=(50, 3))
    for dtype in (np.float32, np.float64):
        for suffix in FORMATS:
            _write_cloud(tmp_path / f"c{suffix}", points.astype(dtype))
            assert np.array_equal(read_cloud(tmp_path / f"c{suffix}"), points.astype(dtype).astype(np.float64)), suffix
    (tmp_path / "ascii.pcd").write_text("VERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
                                        "WIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3 0\n4 5 6.5 0\n")
    assert read_cloud(tmp_path / "ascii.pcd").tolist() == [[1, 2, 3], [4, 5, 6.5]]


def test_scans_through_files_give_the_simulators_grid_and_predicts_pose(scene, checkpoint, tmp_path, capsys):
    scans, poses, expected = scene
    scans_file = _write_scans(tmp_path / "robot", scans, poses)
    answer = _plan(capsys, "--scans", scans_file, "--center", "0,0,0", "--checkpoint", checkpoint,
                   "--save-grid", tmp_path / "grid.npy", "--out", tmp_path / "nbv.json", "--png", tmp_path / "nbv.png")
    grid = np.load(tmp_path / "grid.npy")
    assert grid.dtype == np.float32 and np.array_equal(grid, expected), f"{(grid != expected).sum()} voxels differ"
    assert json.loads((tmp_path / "nbv.json").read_text()) == answer
    assert (tmp_path / "nbv.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    counts = answer["grid"]
    assert counts["occupied"] == (expected > 0.5).sum() and counts["unknown"] == (expected == 0.5).sum() > 0
    assert counts["occupied"] + counts["free"] + counts["unknown"] == 32 ** 3

    np.save(tmp_path / "sim.npy", expected)
    assert main(["predict", str(tmp_path / "sim.npy"), "--checkpoint", str(checkpoint)]) == 0
    predicted = json.loads(capsys.readouterr().out)
    assert answer["position"] == predicted["position"] and answer["network_output"] == predicted["network_output"]
    assert [answer[a] for a in ("yaw", "pitch", "roll")] == [predicted[a] for a in ("yaw", "pitch", "roll")]
    # The pose's other forms say the same: a look-at camera at the position, image rows horizontal.
    matrix = np.array(answer["matrix"])
    assert np.array_equal(matrix[:3, 3], answer["position"]) and np.array_equal(matrix[3], [0, 0, 0, 1])
    rotation = Rotation.from_quat(answer["quaternion_xyzw"]).as_matrix()
    np.testing.assert_allclose(rotation, matrix[:3, :3], atol=1e-12)
    np.testing.assert_allclose(matrix[:3, 2], -np.array(answer["position"]) / 0.4, atol=1e-12)  # looks at the centre
    assert abs(matrix[2, 0]) < 1e-12  # camera x (image right) is horizontal


def test_an_octomap_of_the_same_scans_gives_the_same_grid(tmp_path, checkpoint, capsys):
    """At 1 cm (the fixed-cube scene), where the map's voxels are the grid's: .ot exactly, .bt
    (OctoMap's binary format keeps only occupied/free) in every voxel's state."""
    pyoctomap = pytest.importorskip("pyoctomap", reason="pip install pyoctomap (a test dependency)")
    config = load_config(SimConfig, FIXED_CUBE)
    scans, poses, expected = _simulate(config)
    grid_config = config.scene_grid
    assert grid_config.resolution == 0.01
    tree = pyoctomap.OcTree(0.01)
    for setter, value in [(tree.setProbHit, grid_config.prob_hit), (tree.setProbMiss, grid_config.prob_miss),
                          (tree.setClampingThresMin, grid_config.clamp_min),
                          (tree.setClampingThresMax, grid_config.clamp_max)]:
        setter(value)
    for scan in scans:
        tree.insertPointCloud(scan.points.astype(np.float64), scan.origin.astype(np.float64),
                              max_range=config.sensor.far)
    assert tree.write(str(tmp_path / "map.ot")) and tree.writeBinary(str(tmp_path / "map.bt"))
    common = ["--center", "0,0,0", "--size", "0.24", "--config", FIXED_CUBE, "--checkpoint", checkpoint]
    answer = _plan(capsys, "--octomap", tmp_path / "map.ot", *common, "--save-grid", tmp_path / "ot.npy")
    assert np.array_equal(np.load(tmp_path / "ot.npy"), expected)
    assert answer["octomap"] == {"resolution": 0.01, "exact": True} and answer["grid"]["voxel"] == 0.01
    _plan(capsys, "--octomap", tmp_path / "map.bt", *common, "--save-grid", tmp_path / "bt.npy")
    binary = np.load(tmp_path / "bt.npy")
    for state in (np.greater, np.less, np.equal):
        assert np.array_equal(state(binary, 0.5), state(expected, 0.5)), state
    np.testing.assert_allclose(np.unique(binary), [0.1192, 0.5, 0.971], rtol=1e-6)  # OctoMap's clamps
    # The scans of the same scene through --scans agree with both.
    scans_file = _write_scans(tmp_path / "robot", scans, poses)
    _plan(capsys, "--scans", scans_file, *common, "--save-grid", tmp_path / "scans.npy")
    assert np.array_equal(np.load(tmp_path / "scans.npy"), expected)
    # Off the key grid the rule still gives a grid, and says it is resampled.
    answer = _plan(capsys, "--octomap", tmp_path / "map.ot", *common[2:], "--center", "0.004,0,0")
    assert answer["octomap"]["exact"] is False


def test_translating_and_scaling_the_scene_moves_the_answer_exactly(scene, checkpoint, tmp_path, capsys):
    scans, poses, expected = scene
    base = _plan(capsys, "--scans", _write_scans(tmp_path / "base", scans, poses), "--center", "0,0,0",
                 "--checkpoint", checkpoint)
    shift = np.array([1.5, -2.25, 0.75])
    for scale in (1.0, 2.0):  # a scene twice as large: --size twice the training object's, k = 2
        move = np.diag([scale, scale, scale, 1.0])
        move[:3, 3] = shift
        scans_file = _write_scans(tmp_path / f"moved{scale}", scans, poses, move, dtype=np.float64)
        answer = _plan(capsys, "--scans", scans_file, "--center", ",".join(map(str, shift)), "--size",
                       0.136 * scale, "--checkpoint", checkpoint, "--save-grid", tmp_path / "moved.npy")
        assert np.array_equal(np.load(tmp_path / "moved.npy"), expected)
        assert answer["position"] == (shift + scale * np.array(base["position"])).tolist()
        assert np.array_equal(np.array(answer["matrix"])[:3, :3], np.array(base["matrix"])[:3, :3])
        assert answer["object"]["k"] == scale and answer["view_radius"] == 0.4 * scale
        assert answer["max_range"] == scale and answer["grid"]["side"] == base["grid"]["side"] * scale


def test_the_maximum_range_is_in_world_metres(scene, checkpoint, tmp_path, capsys):
    """A point farther than --max-range from its sensor marks nothing and carves free space to
    that range, as OctoMap's insertPointCloud(maxrange): in a scene twice as large, 0.7 m is the
    simulator's 0.35 m, which cuts the rays short of the object's far side."""
    scans, poses, _ = scene
    expected = OccupancyGrid(SimConfig().scene_grid)
    for scan in scans:
        expected.integrate(scan, 0.35)
    move = np.diag([2.0, 2.0, 2.0, 1.0])
    scans_file = _write_scans(tmp_path / "large", scans, poses, move, dtype=np.float64)
    answer = _plan(capsys, "--scans", scans_file, "--center", "0,0,0", "--size", 0.272, "--max-range", 0.7,
                   "--checkpoint", checkpoint, "--save-grid", tmp_path / "grid.npy")
    assert np.array_equal(np.load(tmp_path / "grid.npy"), expected.probabilities()) and answer["max_range"] == 0.7
    assert answer["grid"]["occupied"] < (scene[2] > 0.5).sum()


@pytest.mark.parametrize("up", ["y", "-x", "-z"])
def test_a_world_with_another_vertical_gives_the_same_grid_and_the_turned_answer(scene, checkpoint, up, tmp_path,
                                                                                   capsys):
    scans, poses, expected = scene
    base = _plan(capsys, "--scans", _write_scans(tmp_path / "base", scans, poses), "--center", "0,0,0",
                 "--checkpoint", checkpoint)
    turn = np.eye(4)
    turn[:3, :3] = up_rotation(up).T  # the scene stood on its side: the world's vertical is now `up`
    center = np.array([0.3, -0.2, 1.1])
    turn[:3, 3] = center
    scans_file = _write_scans(tmp_path / "turned", scans, poses, turn, dtype=np.float64)
    answer = _plan(capsys, "--scans", scans_file, "--center", ",".join(map(str, center)), f"--up={up}",
                   "--checkpoint", checkpoint, "--save-grid", tmp_path / "turned.npy")
    assert np.array_equal(np.load(tmp_path / "turned.npy"), expected)
    assert answer["network_output"] == base["network_output"]
    expected_matrix = turn @ np.array(base["matrix"])
    np.testing.assert_allclose(answer["matrix"], expected_matrix, rtol=0, atol=1e-15)
    vertical = np.array({"y": [0, 1, 0], "-x": [-1, 0, 0], "-z": [0, 0, -1]}[up])
    assert abs(np.array(answer["matrix"])[:3, 0] @ vertical) < 1e-12  # image rows level in the robot's world


class UnknownCentroid:
    """A planner equivariant by construction: look from the side where the unknown voxels lie."""

    name, epoch, radius, view_units = "unknown-centroid", 0, 0.4, None

    def next_view(self, grid, taken, cloud=None):
        centres = OccupancyGrid(SimConfig().scene_grid).voxel_centres()
        mean = centres[grid == 0.5].mean(axis=0)
        direction = np.array([mean[0], mean[1], abs(mean[2])]) / np.linalg.norm(mean)
        return NBVPrediction(direction, direction, Pose.look_at(direction * self.radius))


@pytest.mark.parametrize("turns", [1, 2, 3])
def test_quarter_turns_about_the_vertical_turn_the_grid_exactly_and_an_equivariant_answer(scene, tmp_path, turns):
    """The grid of the turned scene is the turned grid, voxel for voxel; the answer turns with it
    as far as the network is equivariant: exactly for a planner that is (here), not in general for
    a trained network (README: Using a trained network on your robot)."""
    scans, poses, expected = scene
    base = plan(np.zeros(3), scans=_write_scans(tmp_path / "base", scans, poses), planner=UnknownCentroid())
    turn = np.eye(4)
    c, s = [(0, 1), (-1, 0), (0, -1)][turns - 1]
    turn[:2, :2] = [[c, -s], [s, c]]
    turn[:3, 3] = [2.0, 1.0, 0.5]
    scans_file = _write_scans(tmp_path / "turned", scans, poses, turn, dtype=np.float64)
    turned = plan(turn[:3, 3], scans=scans_file, planner=UnknownCentroid())
    assert np.array_equal(turned.grid, np.rot90(expected, turns, axes=(0, 1)))
    np.testing.assert_allclose(turned.pose.matrix, turn @ base.pose.matrix, rtol=0, atol=1e-12)


def test_a_classification_checkpoint_plans_one_of_its_views(scene, tmp_path, capsys):
    scans, poses, expected = scene
    checkpoint = _checkpoint(tmp_path / "class.pt", "nbvnet-class")
    answer = _plan(capsys, "--scans", _write_scans(tmp_path / "robot", scans, poses), "--center", "0,0,0",
                   "--checkpoint", checkpoint)
    np.save(tmp_path / "sim.npy", expected)
    assert main(["predict", str(tmp_path / "sim.npy"), "--checkpoint", str(checkpoint)]) == 0
    assert answer["position"] == json.loads(capsys.readouterr().out)["position"]
    assert answer["model"] == "nbvnet-class"


def _tree(tmp_path: Path, points: np.ndarray, origin) -> Path:
    pyoctomap = pytest.importorskip("pyoctomap", reason="pip install pyoctomap (a test dependency)")
    tree = pyoctomap.OcTree(0.01)
    tree.insertPointCloud(points, np.asarray(origin, dtype=np.float64), max_range=-1.0)
    tree.writeBinary(str(tmp_path / "map.bt"))
    return tmp_path / "map.bt"


def _bad_case(case: str, tmp_path: Path, scene) -> tuple[list[str], list[str]]:
    """(plan arguments, expected parts of the message) for one kind of bad input."""
    scans, poses, _ = scene
    good = _write_scans(tmp_path / "robot", scans[:2], poses[:2])
    entries = yaml.safe_load(good.read_text())
    scan_args = ["--scans", str(good), "--center", "0,0,0"]

    def with_entry(change) -> list[str]:
        change(entries[0])
        good.write_text(yaml.safe_dump(entries))
        return scan_args

    cloud = tmp_path / "robot" / entries[0]["cloud"]
    if case == "empty cloud":
        np.save(cloud.with_suffix(".npy"), np.zeros((0, 3)))
        return with_entry(lambda e: e.update(cloud=cloud.with_suffix(".npy").name)), ["scan 1", "holds no points"]
    if case == "unreadable cloud":
        cloud.write_bytes(b"\x00\x01 not a point cloud")
        return scan_args, [f"scan 1: {cloud}: not a PLY file"]
    if case == "missing cloud":
        cloud.unlink()
        return scan_args, [str(cloud), "no such point cloud file"]
    if case == "NaN points":
        points = read_cloud(cloud)
        points[::100] = np.nan
        _write_cloud(cloud, points)
        return scan_args, [str(cloud), "NaN or infinite", "np.isfinite"]
    if case == "camera-frame cloud":  # (of hits only, as a real sensor's: all in front of the sensor)
        points = read_cloud(cloud)[scans[0].hit]
        matrix = np.array(entries[0]["pose"])
        _write_cloud(cloud, (points - matrix[:3, 3]) @ matrix[:3, :3])
        return scan_args, ["scan 1", "looks like camera-frame points", "world-frame points"]
    if case == "inverted pose":
        return with_entry(lambda e: e.update(pose=np.linalg.inv(np.array(e["pose"])).tolist())), [
            "scan 1", "lie behind the sensor of its pose", "the pose looks inverted (world-to-camera)",
            "in front of its inverse's", "tell by the depths"]
    if case == "pose with scale":
        return with_entry(lambda e: e.update(pose=(np.diag([2, 2, 2, 1]) @ np.array(e["pose"])).tolist())), [
            "scan 1: pose is not a rigid transform", "without scale"]
    if case == "pose a reflection":
        return with_entry(lambda e: e.update(pose=(np.diag([1, 1, -1, 1]) @ np.array(e["pose"])).tolist())), [
            "scan 1: pose is a reflection"]
    if case == "pose not 4x4":
        return with_entry(lambda e: e.update(pose=[1, 2, 3])), ["scan 1: pose is '[1, 2, 3]'", "4x4"]
    if case == "no pose":
        return with_entry(lambda e: e.pop("pose")), [f"{good}: scan 1: no sensor pose", "camera-to-world"]
    if case == "misspelt key":
        return with_entry(lambda e: e.update(quaternion=e.pop("pose"))), ["did you mean 'quaternion_xyzw'"]
    if case == "quaternion not unit":
        entries[1]["quaternion_xyzw"] = [0, 0, 0, 2]
        good.write_text(yaml.safe_dump(entries))
        return scan_args, ["scan 2: quaternion_xyzw", "has norm 2", "unit quaternion"]
    if case == "not a scans file":
        good.write_text("cloud: a.ply\n")
        return scan_args, [str(good), "non-empty YAML list"]
    if case == "size 0":
        return scan_args + ["--size", "0"], ["argument --size: must be a positive finite number, not '0'"]
    if case == "size negative":
        return scan_args + ["--size=-0.3"], ["argument --size: must be a positive finite number, not '-0.3'"]
    if case == "bad centre":
        return ["--scans", str(good), "--center", "0,0"], ["--center '0,0': expected three numbers"]
    if case == "centre off the object":
        return ["--scans", str(good), "--center", "3,0,0"], ["no occupied voxel in the object box", "--center 3,0,0"]
    if case == "bad up":
        return scan_args + ["--up", "w"], ["--up 'w'", "x, y, z, -x, -y, -z"]
    if case == "scene of another radius":
        return scan_args + ["--set", "views.radius=0.5"], ["trained with views at 0.4 m", "views.radius 0.5 m",
                                                           "--config"]
    if case == "grid not .npy":
        return scan_args + ["--save-grid", str(tmp_path / "grid.txt")], ["--save-grid", "name a .npy file"]
    if case == "centre outside the map":
        bt = _tree(tmp_path, np.array([[0.5, 0.0, 0.0], [0.5, 0.1, 0.1]]), [0.9, 0.0, 0.0])
        return ["--octomap", str(bt), "--center", "0,0,0"], ["--center 0,0,0 lies outside the map", str(bt)]
    if case == "map not covering the box":
        bt = _tree(tmp_path, np.array([[0.02, 0.0, 0.0], [0.02, 0.03, 0.03]]), [0.2, 0.0, 0.0])
        return ["--octomap", str(bt), "--center", "0.1,0,0"], [f"the map {bt} does not cover the object box"]
    if case == "not an octomap":
        (tmp_path / "map.bt").write_text("# Octomap OcTree binary file\ngarbage\n")
        return ["--octomap", str(tmp_path / "map.bt"), "--center", "0,0,0"], [str(tmp_path / "map.bt"),
                                                                              "not a readable OctoMap"]
    if case == "max range with a map":
        bt = _tree(tmp_path, np.array([[0.02, 0.0, 0.0]]), [0.2, 0.0, 0.0])
        return ["--octomap", str(bt), "--center", "0,0,0", "--max-range", "2"], ["--max-range applies to --scans"]
    raise AssertionError(case)


BAD = ["empty cloud", "unreadable cloud", "missing cloud", "NaN points", "camera-frame cloud", "inverted pose",
       "pose with scale",
       "pose a reflection", "pose not 4x4", "no pose", "misspelt key", "quaternion not unit", "not a scans file",
       "size 0", "size negative", "bad centre", "centre off the object", "bad up", "scene of another radius",
       "grid not .npy", "centre outside the map",
       "map not covering the box", "not an octomap", "max range with a map"]


@pytest.mark.parametrize("case", BAD)
def test_bad_input_is_one_line_and_exit_2(case, scene, checkpoint, tmp_path, capsys):
    argv, expected = _bad_case(case, tmp_path, scene)
    try:
        status = main(["plan", *argv, "--checkpoint", str(checkpoint)])
    except SystemExit as stop:  # a value the option's type refuses: argparse's one line
        status = stop.code
    assert status == 2
    _one_line_error(capsys, *expected)


def test_without_a_checkpoint_it_uses_the_released_ranker_and_the_score_network_is_a_flag_away(scene, tmp_path,
                                                                                                  capsys):
    scans, poses, _ = scene
    scans_file = str(_write_scans(tmp_path, scans, poses))
    assert main(["plan", "--scans", scans_file, "--center", "0,0,0"]) == 0
    answer = json.loads(capsys.readouterr().out)
    taken = scanned_views(np.array([pose.position for pose in poses]), view_sphere(SimConfig().views).unit_positions)
    assert answer["model"] == "viewrank-gbm" and not taken[answer["view"]]
    assert main(["plan", "--scans", scans_file, "--center", "0,0,0", "--checkpoint",
                 str(ROOT / "nbvtrain" / "released" / "nbvscore-fc3.pt")]) == 0
    assert json.loads(capsys.readouterr().out)["model"] == "nbvscore-fc3"


def _score_checkpoint(path: Path) -> Path:
    """A score network whose favourites are the views VIEWS the scans took."""
    units = view_sphere(SimConfig().views).unit_positions
    torch.manual_seed(0)
    net = build_model("nbvscore-fc3", views=units)
    with torch.no_grad():  # make the scanned views the network's favourites
        net.joint_head[-1].bias[list(VIEWS)] += 100.0
    save_training_state(path, net, torch.optim.Adam(net.parameters()), TrainConfig(model="nbvscore-fc3"), [], 0, 0.4, None, units)
    return path


def test_a_score_network_never_answers_a_view_the_scans_took(scene, tmp_path, capsys):
    """The scans' sensor poses mark their candidate views; the answer is the best other one,
    the same as nbvtrain predict on the same grid with those views scanned, and plan's JSON says
    which view and which scanned ones as predict's does."""
    scans, poses, grid = scene
    units = view_sphere(SimConfig().views).unit_positions
    path = _score_checkpoint(tmp_path / "scores.pt")
    assert main(["plan", "--scans", str(_write_scans(tmp_path, scans, poses)), "--center", "0,0,0",
                 "--checkpoint", str(path), "--save-grid", str(tmp_path / "grid.npy")]) == 0
    planned = json.loads(capsys.readouterr().out)
    view = int(np.argmax(units @ np.array(planned["position"]) / np.linalg.norm(planned["position"])))
    assert view not in VIEWS
    assert main(["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(path), "--scanned",
                 ",".join(map(str, VIEWS))]) == 0
    predicted = json.loads(capsys.readouterr().out)
    assert predicted["view"] == view and predicted["scanned"] == sorted(VIEWS)
    assert planned["view"] == view and planned["scanned"] == sorted(VIEWS)
    np.testing.assert_allclose(planned["position"], predicted["position"], atol=1e-9)
    assert main(["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(path)]) == 0
    assert json.loads(capsys.readouterr().out)["view"] in VIEWS  # told nothing, it takes a favourite


def _legend(result) -> list[str]:
    import matplotlib.pyplot as plt

    figure = draw_plan(result)
    texts = [text.get_text() for legend in figure.legends for text in legend.get_texts()]
    plt.close(figure)
    return texts


def test_the_picture_names_the_candidate_view_and_counts_the_scans(scene, checkpoint, tmp_path):
    """The red arrow of a score network's answer names its candidate view (the JSON's "view"); the
    green ones are the scans, counted as such, never as candidate views; a regression network's
    answer is no candidate view and names none. An OctoMap has no scans to draw."""
    scans, poses, _ = scene
    scans_file = _write_scans(tmp_path / "robot", scans, poses)
    scored = plan(np.zeros(3), scans=scans_file, checkpoint=_score_checkpoint(tmp_path / "scores.pt"))
    view = scored.to_dict()["view"]
    assert view not in VIEWS
    texts = _legend(scored)
    scans_taken = f"scans taken ({len(VIEWS)}, numbered in scan order)"
    assert any(text.startswith(f"next-best-view (view {view}") for text in texts) and scans_taken in texts, texts
    assert "candidate views (500)" in texts
    regressed = plan(np.zeros(3), scans=scans_file, checkpoint=checkpoint)
    assert "view" not in regressed.to_dict() and "scanned" not in regressed.to_dict()
    texts = _legend(regressed)
    assert any(text.startswith("next-best-view") and "(view " not in text for text in texts)  # no candidate named
    assert scans_taken in texts and "candidate views (500)" in texts
    pyoctomap = pytest.importorskip("pyoctomap", reason="pip install pyoctomap (a test dependency)")
    tree = pyoctomap.OcTree(0.005)
    for scan in scans:
        tree.insertPointCloud(scan.points.astype(np.float64), scan.origin.astype(np.float64), max_range=1.0)
    tree.writeBinary(str(tmp_path / "map.bt"))
    mapped = plan(np.zeros(3), octomap=tmp_path / "map.bt", checkpoint=_score_checkpoint(tmp_path / "scores.pt"))
    assert mapped.to_dict()["scanned"] == [] and not any("scans" in text for text in _legend(mapped))


def test_the_frame_maps_there_and_back(rng):
    frame = ObjectFrame(np.array([1.0, -2.0, 0.5]), up_rotation(np.array([0.3, 0.2, 0.9])), 2.5)
    points = rng.normal(size=(20, 3))
    np.testing.assert_allclose(frame.to_world(frame.to_object(points)), points, atol=1e-12)
    np.testing.assert_allclose(frame.up, np.array([0.3, 0.2, 0.9]) / np.linalg.norm([0.3, 0.2, 0.9]), atol=1e-12)
    for name, vector in {"y": [0, 1, 0], "-x": [-1, 0, 0], "-z": [0, 0, -1], "z": [0, 0, 1]}.items():
        rotation = up_rotation(name)
        assert np.array_equal(rotation @ vector, [0, 0, 1]) and set(np.unique(rotation)) <= {-1.0, 0.0, 1.0}
        assert np.linalg.det(rotation) == 1.0
    with pytest.raises(PlanError, match="zero vector"):
        up_rotation("0,0,0")
    assert issubclass(SensorDataError, ValueError)


def test_spread_takes_the_unscanned_view_the_evaluations_rule_takes(scene, checkpoint, tmp_path, capsys):
    """``--spread W`` answers what ``nbvtrain evaluate --spread W`` would: ``spread_view`` of the
    network's answer on the scene's candidate views, never a view the scans took; a large W is the
    view farthest from the scans."""
    from nbvdata.core.views import farthest_view, spread_view
    scans, poses, _ = scene
    scans_file = _write_scans(tmp_path / "robot", scans, poses)
    argv = ["--scans", scans_file, "--center", "0,0,0", "--checkpoint", checkpoint]
    plain = _plan(capsys, *argv)
    views = view_sphere(SimConfig().views)
    positions = np.array([pose.position for pose in poses])
    for weight in (0.0, 2.0, 1e6):
        answer = _plan(capsys, *argv, "--spread", weight, "--png", tmp_path / "spread.png")
        assert answer["network_output"] == plain["network_output"] and answer["spread"] == weight
        assert sorted(answer["scanned"]) == sorted(VIEWS) and answer["view"] not in VIEWS
        assert answer["view"] == spread_view(views.unit_positions, positions, np.array(plain["network_output"]), weight)
        np.testing.assert_allclose(answer["position"], views[answer["view"]].position, atol=1e-12)
    assert answer["view"] == farthest_view(views.unit_positions, positions)
    assert "view" not in plain and plain["position"] != answer["position"]
    # an OctoMap holds no scan positions; a score network reads the scans already
    bt = _tree(tmp_path, np.array([[0.02, 0.0, 0.0]]), [0.2, 0.0, 0.0])
    assert main(["plan", "--octomap", str(bt), "--center", "0,0,0", "--spread", "1"]) == 2
    _one_line_error(capsys, "--spread", "give --scans")
    assert main(["plan", "--scans", str(scans_file), "--center", "0,0,0", "--spread", "1"]) == 2
    _one_line_error(capsys, "--spread: viewrank-gbm scores candidate views", "drop --spread")  # the default: the ranker
    assert main(["plan", "--scans", str(scans_file), "--center", "0,0,0", "--spread", "1", "--checkpoint",
                 str(ROOT / "nbvtrain" / "released" / "nbvscore-fc3.pt")]) == 2
    _one_line_error(capsys, "--spread: nbvscore-fc3 scores candidate views", "drop --spread")
    with pytest.raises(SystemExit):
        main(["plan", *map(str, argv), "--spread=-1"])
    _one_line_error(capsys, "argument --spread")


def test_a_network_told_the_scans_is_handed_the_scans_sensor_positions(scene, tmp_path, capsys):
    from nbvtrain.networks.predict import Predictor
    scans, poses, expected = scene
    path = _checkpoint(tmp_path / "scans.pt", "nbvnet-4-3-scans")
    answer = _plan(capsys, "--scans", _write_scans(tmp_path / "robot", scans, poses), "--center", "0,0,0",
                   "--checkpoint", path)
    predictor = Predictor(path)
    positions = np.array([pose.position for pose in poses])
    told, blind = predictor.raw(expected, scans=positions)[0], predictor.raw(expected)[0]
    np.testing.assert_allclose(answer["network_output"], told, atol=1e-6)
    assert not np.allclose(told, blind, atol=1e-4)
