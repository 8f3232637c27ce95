"""The ideas issue 27 measures on validation objects, as planners: an ensemble of score networks
(standardised scores, one vote each), quarter-turn test-time averaging where it is exact, and a
hybrid of the score network and information gain. Untrained (seeded) networks: the planners'
arithmetic, not their quality."""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from nbvdata.core.config import ConfigError, SimConfig, load_config
from nbvdata.core.views import sphere_positions, view_sphere
from nbvdata.simulation.episode import Reconstruction, scene_rng
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.shapes import BUILTIN_SHAPES, builtin_object
from nbvtrain.cli import main
from nbvtrain.evaluation.evaluate import reconstruct
from nbvtrain.networks.checkpoint import load_checkpoint
from nbvtrain.networks.config import TrainConfig
from nbvtrain.networks.models import build_model, quarter_turns
from nbvtrain.networks.predict import Predictor
from nbvtrain.networks.scores import pick, standardise
from nbvtrain.networks.train import save_training_state
from nbvtrain.networks.trained_scene import scene_record
from nbvtrain.planners import HybridPlanner, InfoGainPlanner, LearnedPlanner, Observation

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs" / "smoke.yaml"


@pytest.fixture(scope="module")
def config() -> SimConfig:
    return load_config(SimConfig, SMOKE)


@pytest.fixture(scope="module")
def scene(config) -> Scene:
    obj = builtin_object("mug", config.mesh)
    return Scene.build(obj, config, scene_rng(0, obj.mesh_id))


def _save_model(path: Path, model, config: SimConfig | None, units: np.ndarray) -> Path:
    scene = scene_record(config) if config is not None else None
    save_training_state(path, model, torch.optim.Adam(model.parameters()), TrainConfig(model=model.name), [], 0, 0.4, scene, units)
    return path


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory, config) -> dict[str, Path]:
    """Seeded untrained networks of the smoke scene; ``scaled``: ``score-b`` with its scores times
    1000 plus 7 (its last layer scaled and shifted)."""
    folder = tmp_path_factory.mktemp("checkpoints")
    units = view_sphere(config.views).unit_positions
    paths = {}
    for key, name, seed in (("score-a", "nbvscore-3", 0), ("score-b", "nbvscore-3", 1), ("fc3", "nbvscore-fc3", 0),
                            ("regression", "nbvnet-3-3", 0), ("class", "nbvnet-class", 0)):
        torch.manual_seed(seed)
        model = build_model(name, views=units if name.startswith("nbvscore") else None)
        paths[key] = _save_model(folder / f"{key}.pt", model, config, units)
        if key == "score-b":
            last = model.view_head[-1]
            with torch.no_grad():
                last.weight *= 1000
                last.bias.mul_(1000).add_(7)
            paths["scaled"] = _save_model(folder / "scaled.pt", model, config, units)
    return paths


@pytest.fixture(scope="module")
def states(scene) -> list[tuple[np.ndarray, tuple]]:
    """(grid, poses scanned) after 1, 2 and 3 scans of the mug from spread-out views."""
    state = Reconstruction(scene, None, np.random.default_rng(0))
    found = []
    for view in (0, 23, 47):
        state.scan_pose(scene.views[view])
        found.append((state.grid.probabilities(), tuple(scene.views[v] for v in (0, 23, 47)[:len(found) + 1])))
    return found


def test_standardise_keeps_the_order_and_ignores_the_scanned_views(rng):
    scores, free = rng.normal(size=50), rng.random(50) < 0.7
    z = standardise(scores, free)
    assert z[free].mean() == pytest.approx(0, abs=1e-12) and z[free].std() == pytest.approx(1)
    assert np.array_equal(np.argsort(z, kind="stable"), np.argsort(scores, kind="stable"))
    assert np.allclose(standardise(1000 * scores + 7, free), z)  # any positive scale and shift
    other = scores.copy()
    other[~free] = rng.normal(size=(~free).sum()) * 1e6  # what the scanned views score changes nothing
    assert np.allclose(standardise(other, free)[free], z[free])
    assert np.array_equal(standardise(np.full(5, 3.0), np.ones(5, bool)), np.zeros(5))  # no spread: centred


def test_an_ensemble_of_one_network_is_that_network(scene, states, checkpoints):
    alone = Predictor(checkpoints["score-a"])
    for paths in ([checkpoints["score-a"]], [checkpoints["score-a"]] * 2):
        planner = LearnedPlanner(paths, 0.4, "scores", scene.views)
        assert planner.name == ("scores" if len(paths) == 1 else "scores-ens2")
        for grid, poses in states:
            taken = planner.scanned(Observation(grid, poses))
            expected = int(pick(alone.raw(grid, taken), taken[None])[0])
            assert planner.next_view(Observation(grid, poses)) == expected and not taken[expected]


def test_an_ensemble_gives_each_network_one_vote_whatever_its_scale(scene, states, checkpoints):
    a, b, scaled = (Predictor(checkpoints[key]) for key in ("score-a", "score-b", "scaled"))
    ensemble = LearnedPlanner([checkpoints["score-a"], checkpoints["score-b"]], 0.4, "scores", scene.views)
    rescaled = LearnedPlanner([checkpoints["score-a"], checkpoints["scaled"]], 0.4, "scores", scene.views)
    for grid, poses in states:
        taken = ensemble.scanned(Observation(grid, poses))
        assert np.allclose(scaled.raw(grid, taken), 1000 * b.raw(grid, taken) + 7, rtol=1e-4)  # the copy is scaled
        mixed = ensemble.view_scores(Observation(grid, poses), taken)
        assert np.allclose(rescaled.view_scores(Observation(grid, poses), taken), mixed, atol=1e-4)
        assert ensemble.next_view(Observation(grid, poses)) == rescaled.next_view(Observation(grid, poses))
        assert not np.allclose(mixed, standardise(a.raw(grid, taken)[0], ~taken), atol=1e-3)  # b counts
        # a plain mean would be b's choice alone: the scaled network drowns the other
        raw_mean = a.raw(grid, taken) + scaled.raw(grid, taken)
        assert pick(raw_mean, taken[None])[0] == pick(b.raw(grid, taken), taken[None])[0]


def _closed_views() -> np.ndarray:
    """(60, 3) unit directions closed under quarter turns about z: 15 directions and their turns."""
    base = sphere_positions(15, 1.0, "hemisphere")
    return np.concatenate([quarter_turns(base, turn) for turn in range(4)])


def test_quarter_turn_averaging_turns_exactly_with_the_object(tmp_path, states, rng):
    """Averaged over the four turns, the answer for the object turned is the answer turned, for any
    weights: a score network's view v scores what the turned view scores, a regression network's
    position turns along. The plain answers do not (the untrained networks are not symmetric)."""
    units = _closed_views()
    torch.manual_seed(3)
    scores = _save_model(tmp_path / "score.pt", build_model("nbvscore-3", views=units), None, units)
    torch.manual_seed(4)
    regression = _save_model(tmp_path / "regression.pt", build_model("nbvnet-3-3"), None, units)
    grid = states[1][0]
    taken = rng.random(len(units)) < 0.2
    for tta in (True, False):
        score_net, regression_net = Predictor(scores, tta=tta), Predictor(regression, tta=tta)
        answer, position = score_net.raw(grid, taken)[0], regression_net.raw(grid)[0]
        for turn in (1, 2, 3):
            turned = np.ascontiguousarray(np.rot90(grid, turn, axes=(0, 1)))
            # view v of the turned object is the view at v's direction turned
            moved = np.array([np.argmax(units @ u) for u in quarter_turns(units, turn)])
            taken_turned = np.zeros_like(taken)
            taken_turned[moved] = taken
            same = np.allclose(score_net.raw(turned, taken_turned)[0][moved], answer, rtol=1e-5, atol=1e-6)
            turns_along = np.allclose(regression_net.raw(turned)[0], quarter_turns(position[None], turn)[0],
                                      rtol=1e-5, atol=1e-7)
            assert same == tta and turns_along == tta, (tta, turn)


def test_quarter_turn_averaging_of_an_equivariant_network_is_its_plain_answer(tmp_path, states, checkpoints):
    """Convolutions that see nothing (zero weights: constant features), and a head blind to the
    views' horizontal directions: every turn gives the same scores, so their mean is the plain
    answer, up to float rounding (each turn pools the cells with other weights). Likewise a
    regression network blind to the grid that answers straight up."""
    state = load_checkpoint(checkpoints["score-a"])
    units = state["view_units"].double().numpy()
    model = build_model("nbvscore-3", views=units)
    model.load_state_dict(state["state_dict"])
    with torch.no_grad():
        for layer in model.features:
            if isinstance(layer, torch.nn.Conv3d):
                layer.weight.zero_()
        first = model.view_head[0]
        channels = [layer for layer in model.features if isinstance(layer, torch.nn.Conv3d)][-1].out_channels
        direction = channels + model.global_head[0].out_features  # the inputs after the side and whole grid's
        first.weight[:, direction:direction + 2] = 0  # the x and y of the view's direction
    path = _save_model(tmp_path / "symmetric.pt", model, None, units)
    torch.manual_seed(5)
    regression = build_model("nbvnet-3-3")
    with torch.no_grad():
        for layer in regression.features:
            if isinstance(layer, torch.nn.Conv3d):
                layer.weight.zero_()
        regression.head[-2].weight[:2] = 0
        regression.head[-2].bias[:2] = 0
    upright = _save_model(tmp_path / "upright.pt", regression, None, units)
    for grid, _ in states:
        plain, averaged = Predictor(path).raw(grid), Predictor(path, tta=True).raw(grid)
        assert np.allclose(averaged, plain, rtol=1e-6, atol=1e-7) and np.ptp(plain) > 0
        assert np.allclose(Predictor(upright, tta=True).raw(grid), Predictor(upright).raw(grid), rtol=1e-6, atol=1e-9)


def test_quarter_turn_averaging_is_refused_where_it_is_not_exact(checkpoints, tmp_path, capsys):
    for key, what in (("fc3", "its candidate views, which are outputs"), ("class", "its 14 class views")):
        with pytest.raises(ConfigError, match=what):
            Predictor(checkpoints[key], tta=True)
    mug = tmp_path / "mug.obj"
    BUILTIN_SHAPES["mug"]().export(mug)
    assert main(["evaluate", "--meshes", str(mug), "--planners", "scores", "--score-checkpoint",
                 str(checkpoints["fc3"]), "--tta", "--config", str(SMOKE), "--out", str(tmp_path / "eval")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "drop --tta" in err and not (tmp_path / "eval").exists()
    assert main(["predict", str(tmp_path / "none.npy"), "--checkpoint", str(checkpoints["class"]), "--tta"]) == 2
    assert "not exact for nbvnet-class" in capsys.readouterr().err


def _poses(rows: list[dict]) -> list[tuple]:
    return [tuple(np.round([row[k] for k in "xyz"], 9)) for row in rows]


def test_the_hybrid_with_weight_0_is_the_score_network(scene, config, checkpoints):
    for paths in ([checkpoints["score-a"]], [checkpoints["score-a"], checkpoints["score-b"]]):
        network = LearnedPlanner(paths, 0.4, "scores", scene.views, config=config)
        hybrid = HybridPlanner(paths, config, scene.views, 0.0)
        assert hybrid.name == "hybrid-w0" + network.name.removeprefix("scores")
        for first in (0, 31):
            assert _poses(reconstruct(scene, hybrid, first, 8, seed=0)) == _poses(
                reconstruct(scene, network, first, 8, seed=0))


@pytest.mark.parametrize("stride", [1, 2])
def test_the_hybrid_with_a_huge_weight_is_information_gains_choice_among_valid_views(scene, config, states,
                                                                                    checkpoints, stride):
    """Information gain over the candidate views from a ``stride`` times coarser image: on states
    where its best valid view adds information, the hybrid takes it; it never takes a scanned view."""
    hybrid = HybridPlanner([checkpoints["score-a"]], config, scene.views, 1e9, stride=stride)
    sensor = dataclasses.replace(config.sensor, width=-(-config.sensor.width // stride),
                                 height=-(-config.sensor.height // stride))
    infogain = InfoGainPlanner(config.scene_grid, sensor, config.views.radius, config.mesh.object_size,
                               config.oracle.min_overlap, count=len(scene.views), layout=config.views.layout)
    compared, rng = 0, np.random.default_rng(0)
    for scans in (2, 3, 4) * 3:  # states after a few scans from random views
        state = Reconstruction(scene, None, np.random.default_rng(0))
        for view in rng.choice(len(scene.views), scans, replace=False):
            state.scan_pose(scene.views[view])
        grid = state.grid.probabilities()
        best = infogain.best_view(grid)
        if infogain.scores(grid).information[best] > 0:  # else infogain re-takes a view that adds nothing
            assert hybrid.next_view(Observation(grid, ())) == best  # no scan marked: infogain's own choice
            compared += 1
    assert compared >= 5
    for grid, poses in states:
        taken = hybrid.scanned(Observation(grid, poses))
        assert not taken[hybrid.next_view(Observation(grid, poses))]
    network = LearnedPlanner([checkpoints["score-a"]], 0.4, "scores", scene.views)
    assert any(network.next_view(Observation(grid, ())) != infogain.best_view(grid) for grid, _ in states)


def test_evaluate_runs_the_ideas_side_by_side(scene, checkpoints, tmp_path, capsys):
    """--score-checkpoint A,B (an ensemble) with --tta, and hybrids of two weights: the weight-0 hybrid
    reconstructs exactly as the score planner; config.yaml records the choices."""
    mug = tmp_path / "mug.obj"
    BUILTIN_SHAPES["mug"]().export(mug)
    out = tmp_path / "eval"
    ensemble = f"{checkpoints['score-a']},{checkpoints['score-b']}"
    assert main(["evaluate", "--meshes", str(mug), "--planners", "scores,hybrid", "--score-checkpoint", ensemble,
                 "--tta", "--hybrid-weight", "0,2.5", "--scans", "5", "--random-starts", "1", "--config", str(SMOKE),
                 "--out", str(out), "--no-progress"]) == 0
    with open(out / "coverage.csv") as handle:
        rows = list(csv.DictReader(handle))
    by = {name: [row for row in rows if row["planner"] == name]
          for name in ("scores-ens2-tta", "hybrid-w0-ens2-tta", "hybrid-w2.5-ens2-tta")}
    assert all(len(planner_rows) == 2 * 5 for planner_rows in by.values())
    strip = [{k: v for k, v in row.items() if k not in ("planner", "seconds")} for row in by["scores-ens2-tta"]]
    assert strip == [{k: v for k, v in row.items() if k not in ("planner", "seconds")}
                     for row in by["hybrid-w0-ens2-tta"]]
    settings = yaml.safe_load((out / "config.yaml").read_text())["evaluate"]
    assert settings["checkpoints"]["scores-ens2-tta"] == ensemble.split(",") and settings["tta"] is True
    assert settings["hybrid_weights"] == [0.0, 2.5] and settings["hybrid_stride"] == 4
    for flags, message in ((["--hybrid-weight", "-1"], "must be a number >= 0"),
                           (["--hybrid-weight", "a,b"], "expected comma-separated numbers"),
                           (["--hybrid-stride", "0"], "must be a whole number >= 1")):
        try:
            status = main(["evaluate", "--meshes", str(mug), "--planners", "hybrid", "--score-checkpoint", ensemble,
                           *flags, "--config", str(SMOKE), "--out", str(tmp_path / "bad")])
        except SystemExit as exit_:  # the parser's own check (nbvdata.commandline)
            status = exit_.code
        assert status == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err
