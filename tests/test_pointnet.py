"""nbvscore-pc, the point-cloud score network: shapes, invariance to the points' order, learning
the best view of a tiny synthetic case, training on shards with clouds, and the scores planner
in evaluate, predict and plan fed the clouds the generator would make; bad input one line, exit 2."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from test_plan import _write_scans

from nbvdata.core.cloud import ScannedCloud, reduce_cloud
from nbvdata.core.config import SimConfig, load_config
from nbvdata.core.views import view_sphere
from nbvdata.datasets.generate import generate
from nbvdata.schema.shards import Shard
from nbvdata.simulation.episode import Reconstruction, scene_rng
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.sensor import MeshScanner
from nbvdata.simulation.shapes import builtin_object
from nbvdata.simulation.sources import builtin_sources
from nbvtrain.cli import main
from nbvtrain.evaluation.evaluate import evaluate
from nbvtrain.networks.config import TrainConfig
from nbvtrain.networks.models import MODELS, PointScoreNet, build_model, layer_names
from nbvtrain.networks.predict import Predictor
from nbvtrain.networks.scores import pick, score_loss
from nbvtrain.networks.train import fit
from nbvtrain.planners import LearnedPlanner, Observation

SMOKE = Path(__file__).resolve().parents[1] / "configs" / "smoke.yaml"
PLAN_VIEWS = (3, 17, 40)  # of the smoke scene's 60 views
AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)


def test_the_registry_builds_a_point_network():
    assert MODELS["nbvscore-pc"].inputs == "points" and MODELS["nbvscore-pc"].task == "scores"
    model = build_model("nbvscore-pc", "fc1", 0.3, views=AXES).eval()
    assert isinstance(model, PointScoreNet) and model.inputs == "points"
    scores = model(torch.rand(4, 100, 3) - 0.5, torch.zeros(4, 6, dtype=torch.bool))
    assert scores.shape == (4, 6) and torch.isfinite(scores).all()
    assert layer_names("nbvscore-pc") == ["conv1", "conv2", "conv3", "fc1", "fc2"]
    with pytest.raises(ValueError, match="views=\\(V, 3\\)"):
        build_model("nbvscore-pc")


def test_the_scores_do_not_depend_on_the_order_of_the_points():
    torch.manual_seed(0)
    model = build_model("nbvscore-pc", "none", views=AXES).eval()
    points = torch.rand(3, 512, 3) * 0.1
    taken = torch.zeros(3, 6, dtype=torch.bool)
    taken[1, 2] = True
    with torch.no_grad():
        scores = model(points, taken)
        for seed in range(3):
            order = torch.from_numpy(np.random.default_rng(seed).permutation(512))
            assert torch.allclose(model(points[:, order], taken), scores, rtol=0, atol=1e-6)
        assert not torch.allclose(model(points * 1.5, taken), scores)  # the points do matter
        assert not torch.allclose(model(points, torch.zeros_like(taken)), scores)  # and so does the view state


def _synthetic_batch(rng: np.random.Generator, size: int, points: int = 64):
    """Clouds scattered around the side of the object one of six axis views saw (that view
    scanned): the best next view is the opposite one (gain 1), the four side views gain 0.4, the
    scanned one 0."""
    seen = rng.integers(0, 6, size)
    clouds = (AXES[seen][:, None] + 0.3 * rng.normal(size=(size, points, 3))) * 0.05
    opposite = seen ^ 1
    gains = np.full((size, 6), 0.4)
    gains[np.arange(size), seen] = 0.0
    gains[np.arange(size), opposite] = 1.0
    taken = np.zeros((size, 6), dtype=bool)
    taken[np.arange(size), seen] = True
    return (torch.from_numpy(clouds.astype(np.float32)), torch.from_numpy(gains.astype(np.float32)),
            torch.from_numpy(taken), opposite)


def test_it_learns_to_pick_the_best_view_of_a_tiny_synthetic_case():
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    model = build_model("nbvscore-pc", "none", views=AXES)
    model.point_scale.fill_(1 / 0.05)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    for _ in range(150):
        clouds, gains, taken, _ = _synthetic_batch(rng, 32)
        loss = score_loss(model(clouds, taken), gains, torch.ones_like(taken), taken, "listwise")
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    clouds, gains, taken, opposite = _synthetic_batch(np.random.default_rng(99), 200)
    with torch.no_grad():
        chosen = pick(model.eval()(clouds, taken), taken)
    assert (chosen == opposite).mean() > 0.95
    with torch.no_grad():  # a network that did not learn: about chance among the 5 unscanned views
        untrained = build_model("nbvscore-pc", "none", views=AXES).eval()
        assert (pick(untrained(clouds, taken), taken) == opposite).mean() < 0.6


# ---------------------------------------------------------------------------------------------
# Training on shards and planning with the checkpoint


def _scene_config(*overrides: str) -> SimConfig:
    return load_config(SimConfig, SMOKE, ["state.points=64", *overrides])


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    out = tmp_path_factory.mktemp("clouds")
    generate(builtin_sources()[:2], out, _scene_config("generate.workers=1"))
    return out


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory, shards):
    out = tmp_path_factory.mktemp("run")
    config = TrainConfig(model="nbvscore-pc", epochs=1, batch_size=8, dropout_from="fc1", threads=1)
    result = fit(sorted(shards.glob("*.h5")), config, out, log=lambda line: None)
    assert result.epochs == 1
    return out / "best.pt"


def test_the_checkpoint_records_its_clouds_and_scale(checkpoint):
    state = torch.load(checkpoint, weights_only=True)
    assert state["points"] == 64 and state["model"] == "nbvscore-pc"
    assert torch.isclose(state["state_dict"]["point_scale"], torch.tensor(1 / 0.4))


def test_predict_reads_a_shards_cloud_and_a_cloud_file_alike(shards, checkpoint, tmp_path, capsys):
    path = sorted(shards.glob("*.h5"))[0]
    with Shard(path) as shard:
        cloud, count = shard["points"][2], int(shard["points_count"][2])
    assert main(["predict", str(path), "--index", "2", "--checkpoint", str(checkpoint)]) == 0
    from_shard = json.loads(capsys.readouterr().out)
    np.save(tmp_path / "cloud.npy", cloud[:min(count, 64)])
    scanned = ",".join(map(str, from_shard["scanned"]))
    assert main(["predict", str(tmp_path / "cloud.npy"), "--checkpoint", str(checkpoint), "--scanned", scanned]) == 0
    from_file = json.loads(capsys.readouterr().out)
    assert from_file["view"] == from_shard["view"] and from_file["scanned"] == from_shard["scanned"]
    assert len(from_shard["scanned"]) == 3


def test_the_planner_reduces_a_runs_points_as_the_generator_does(checkpoint):
    """In closed loop the planner gets every scanned point; its choice is the network's on the
    cloud the generator stores for that state."""
    config = _scene_config()
    source = builtin_sources()[0]
    scene = Scene.build(source.load(config.mesh), config, scene_rng(0, source.mesh_id))
    planner = LearnedPlanner(checkpoint, config.views.radius, "scores", scene.views, config=config)
    assert planner.reads_points
    state = Reconstruction(scene, None, np.random.default_rng(0), points=True)
    for view in (4, 30):
        state.scan(view)
    observation = Observation(state.grid.probabilities(), (scene.views[4], scene.views[30]), state.cloud.points())
    stored, _ = state.cloud.reduce(64)  # what the shard would hold
    taken = np.zeros(len(scene.views), dtype=bool)
    taken[[4, 30]] = True
    expected = pick(planner.predictor.raw(stored, taken), taken[None])[0]
    assert planner.next_view(observation) == expected and expected not in (4, 30)


def test_a_state_whose_scans_hit_nothing_is_planned_as_the_generator_stores_it(checkpoint):
    """A start view that sees nothing of a thin object leaves no points: the generator stores
    zeros for such a state, and the planner must answer from the same cloud (it raised before)."""
    config = _scene_config()
    source = builtin_sources()[0]
    scene = Scene.build(source.load(config.mesh), config, scene_rng(0, source.mesh_id))
    planner = LearnedPlanner(checkpoint, config.views.radius, "scores", scene.views, config=config)
    observation = Observation(np.full((32,) * 3, 0.5, dtype=np.float32), (scene.views[4],),
                              np.zeros((0, 3), dtype=np.float32))
    stored, count = reduce_cloud(observation.points, 64)
    assert count == 0 and not stored.any()
    taken = np.zeros(len(scene.views), dtype=bool)
    taken[4] = True
    expected = pick(planner.predictor.raw(stored, taken), taken[None])[0]
    assert planner.next_view(observation) == expected != 4


def test_evaluate_runs_the_point_network_without_repeating_a_view(checkpoint):
    config = _scene_config()
    planners = [LearnedPlanner(checkpoint, config.views.radius, "scores",
                               Scene.build(builtin_sources()[0].load(config.mesh), config,
                                           scene_rng(0, builtin_sources()[0].mesh_id)).views, config=config)]
    report = evaluate(builtin_sources()[:1], planners, config, scans=5)
    assert not report.failures and len(report.rows) == 5
    positions = [(row["x"], row["y"], row["z"]) for row in report.rows]
    assert len(set(positions)) == 5 and report.rows[-1]["coverage"] > report.rows[0]["coverage"]


def test_plan_feeds_the_scans_points_as_the_generator_collects_them(checkpoint, tmp_path, capsys):
    config = _scene_config()
    views = view_sphere(config.views)
    poses = [views[i] for i in PLAN_VIEWS]
    scans = MeshScanner(builtin_object("mug", config.mesh).mesh, config.sensor, threads=1).scan_many(poses)
    scans_file = _write_scans(tmp_path / "robot", scans, poses)
    (tmp_path / "scene.yaml").write_text(SMOKE.read_text() + "state:\n  points: 64\n")
    assert main(["plan", "--scans", str(scans_file), "--center", "0,0,0", "--checkpoint", str(checkpoint),
                 "--config", str(tmp_path / "scene.yaml")]) == 0
    answer = json.loads(capsys.readouterr().out)
    cloud = ScannedCloud()
    for scan in scans:
        cloud.add(scan.hit_points)
    predictor = Predictor(checkpoint)
    taken = np.zeros(len(predictor.view_units), dtype=bool)
    taken[list(PLAN_VIEWS)] = True
    expected = predictor.view_units[pick(predictor.raw(reduce_cloud(cloud.points(), 64)[0], taken), taken[None])[0]]
    assert np.allclose(np.array(answer["position"]) / np.linalg.norm(answer["position"]), expected)


def test_point_network_user_errors_are_one_line_and_exit_2(shards, checkpoint, tmp_path, capsys):
    plain = tmp_path / "plain"
    generate(builtin_sources()[:1], plain, load_config(SimConfig, SMOKE, ["episode.runs_per_mesh=1",
                                                                         "generate.workers=1"]))
    grid_shard = str(sorted(plain.glob("*.h5"))[0])
    (tmp_path / "bad.npy").write_bytes(b"not an array")
    cases = [
        (["fit", grid_shard, "--model", "nbvscore-pc", "--epochs", "1", "--out", str(tmp_path / "r")],
         "holds no point clouds, which nbvscore-pc reads"),
        (["predict", grid_shard, "--checkpoint", str(checkpoint)], "holds no point clouds, which nbvscore-pc reads"),
        (["predict", str(tmp_path / "bad.npy"), "--checkpoint", str(checkpoint)], "not a numpy array file (.npy)"),
        (["fit", str(shards), "--model", "nbvscore-pc", "--augment", "--out", str(tmp_path / "s")],
         "quarter turns apply to grids"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "r").exists()
    from nbvdata.cli import main as nbvdata_main

    assert nbvdata_main(["generate", "--out", str(tmp_path / "p"), "--config", str(SMOKE), "--policy",
                         str(checkpoint)]) == 2
    err = capsys.readouterr().err.strip()
    assert "reads point clouds" in err and len(err.splitlines()) == 1, err
