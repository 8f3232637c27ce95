"""Model files that are damaged are refused in one line before a library parses them: the sha256
of a LightGBM model's text (rankers, cover models) and of a torch file's weights (checkpoints,
viewrank-mlp, scvp-net, RL actors), written by the code that saves them; LightGBM's own logging
stays silent; released files record no path of the machine that made them."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from nbvdata.core.config import SimConfig
from nbvdata.simulation.viewfeatures import BASE, BUNDLE
from nbvtrain.networks.checkpoint import WEIGHTS_KEY, CheckpointError, load_checkpoint
from nbvtrain.planners.released import released_folder
from nbvtrain.ranking._lightgbm import TEXT_KEY, lightgbm
from nbvtrain.ranking.covermodel import CoverModel, load_cover_model
from nbvtrain.ranking.covernet import CoverNetConfig, load_covernet, network, save_covernet
from nbvtrain.ranking.viewrank import ViewRanker, load_ranker, scorer

ROOT = Path(__file__).resolve().parents[1]
SCENE = {"grid_size": 32, "grid_extent": round(float(SimConfig().scene_grid.extent), 9)}


def _overwrite_middle(path: Path, count: int = 64) -> None:
    """64 bytes in the middle of the file's model (its LightGBM text or its weights) made 'x'."""
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle:middle + count] = b"x" * count
    path.write_bytes(bytes(data))


def _cut_model_text(path: Path) -> None:
    """The LightGBM text of a JSON model file cut in half, the file otherwise whole and valid JSON."""
    head = json.loads(path.read_text())
    head["lightgbm"] = head["lightgbm"][:len(head["lightgbm"]) // 2]
    path.write_text(json.dumps(head))


def _booster(rows: int = 400, label=None):
    rng = np.random.default_rng(0)
    features = rng.random((rows, len(BASE))).astype(np.float32)
    labels = (features[:, 2] > 0.5).astype(int) if label is None else label(features)
    params = {"objective": "binary", "verbosity": -1, "num_threads": 1, "deterministic": True, "min_data_in_leaf": 5}
    return lightgbm.train(params, lightgbm.Dataset(features, label=labels), num_boost_round=5)


@pytest.fixture
def cover_file(tmp_path) -> Path:
    path = tmp_path / "cover.json"
    CoverModel(_booster(), BUNDLE, SCENE, 0.5, {"views": ["scvp-32"]}).save(path)
    return path


def test_written_files_carry_their_checksums(cover_file, tmp_path):
    assert TEXT_KEY in json.loads(cover_file.read_text())
    assert TEXT_KEY in json.loads((released_folder() / "viewrank.json").read_text())
    for name in ("nbvscore-fc3.pt", "nbvnet-4-3.pt"):
        assert WEIGHTS_KEY in load_checkpoint(released_folder() / name)


@pytest.mark.parametrize("damage", [_overwrite_middle, _cut_model_text])
def test_a_damaged_lightgbm_model_is_refused_before_lightgbm_reads_it(cover_file, tmp_path, damage):
    ranker = tmp_path / "viewrank.json"
    shutil.copy(released_folder() / "viewrank.json", ranker)
    for path, load in ((ranker, load_ranker), (cover_file, load_cover_model)):
        damage(path)
        with pytest.raises(CheckpointError, match="damaged") as caught:
            load(path)
        assert "\n" not in str(caught.value)


def test_a_damaged_ranker_exits_2_in_one_line_in_its_own_process(tmp_path):
    """The command a user ran (LightGBM aborted it with exit 134 before the checksum): in a
    process of its own, so that a regression cannot take the test run down."""
    ranker = tmp_path / "viewrank.json"
    shutil.copy(released_folder() / "viewrank.json", ranker)
    _overwrite_middle(ranker)
    grid = tmp_path / "g.npy"
    np.save(grid, np.full((32, 32, 32), 0.5, dtype=np.float32))
    done = subprocess.run([sys.executable, "-m", "nbvtrain", "predict", str(grid), "--checkpoint", str(ranker)],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 2, done.stderr[-2000:]
    assert len(done.stderr.strip().splitlines()) == 1 and "damaged" in done.stderr
    assert "LightGBM" not in done.stdout + done.stderr.replace("LightGBM model", "")


def test_lightgbm_says_nothing_while_it_parses(tmp_path, capfd):
    text = "tree\nnonsense"
    path = tmp_path / "cover.json"
    good = tmp_path / "good.json"
    CoverModel(_booster(), BUNDLE, SCENE, 0.5, {}).save(good)
    head = json.loads(good.read_text())
    path.write_text(json.dumps(head | {"lightgbm": text, TEXT_KEY: __import__("hashlib").sha256(text.encode()).hexdigest()}))
    capfd.readouterr()
    with pytest.raises(CheckpointError, match="does not load"):
        load_cover_model(path)
    out, err = capfd.readouterr()
    assert "[LightGBM]" not in out + err


def test_an_unchecked_file_of_before_still_loads(tmp_path, caplog):
    path = tmp_path / "viewrank.json"
    head = json.loads((released_folder() / "viewrank.json").read_text())
    del head[TEXT_KEY]
    path.write_text(json.dumps(head))
    assert load_ranker(path).kind == "viewrank-gbm"
    assert "no checksum" in caplog.text


def _mlp_file(path: Path) -> Path:
    torch.manual_seed(0)
    width = len(BASE)
    ViewRanker("viewrank-mlp", list(BASE), BUNDLE, SCENE, {"hidden": [8]}, network=scorer(width, (8,)),
               mean=np.zeros(width, dtype=np.float32), std=np.ones(width, dtype=np.float32)).save(path)
    return path


def _covernet_file(path: Path) -> Path:
    torch.manual_seed(0)
    model = network(views=4, width=2)
    save_covernet(path, model, CoverNetConfig(width=2), {"view_positions": np.eye(4, 3) * 0.4}, [])
    return path


def _checkpoint_file(path: Path) -> Path:
    shutil.copy(released_folder() / "nbvscore-fc3.pt", path)
    return path


@pytest.mark.parametrize("make, load", [(_mlp_file, load_ranker), (_covernet_file, load_covernet),
                                        (_checkpoint_file, load_checkpoint)])
def test_damaged_torch_weights_are_refused(tmp_path, make, load):
    path = make(tmp_path / "viewrank-model.pt")
    load(path)  # whole: loads
    state = torch.load(path, weights_only=True)
    assert WEIGHTS_KEY in state
    weights = state["state_dict"]
    name = max(weights, key=lambda key: weights[key].numel())
    weights[name].view(-1)[weights[name].numel() // 2] += 1  # one weight changed, the file still a torch file
    torch.save(state, path)
    with pytest.raises(CheckpointError, match="damaged") as caught:
        load(path)
    assert "\n" not in str(caught.value)


def test_an_rl_actor_with_damaged_weights_is_refused(tmp_path):
    import gymnasium

    from nbvtrain.networks.rl import ScoreFeatures, load_actor, save_actor

    views = load_checkpoint(released_folder() / "nbvscore-fc3.pt")["view_units"].double().numpy()
    space = gymnasium.spaces.Dict({"taken": gymnasium.spaces.MultiBinary(len(views))})
    features = ScoreFeatures(space, views)
    head = torch.nn.Linear(len(views), len(views))
    path = tmp_path / "actor.pt"
    save_actor(path, features, head, {"stage": "test"})
    load_actor(path)
    state = torch.load(path, weights_only=True)
    state["head"]["bias"][0] += 1
    torch.save(state, path)
    with pytest.raises(CheckpointError, match="damaged"):
        load_actor(path)


ABSOLUTE = re.compile(r"""(?:^|[\s"'=:(\[])(/(?:work|home|root|tmp|Users|mnt|var|opt)/[^\s"']*)""")


def _strings(value) -> list[str]:
    if isinstance(value, dict):
        return [text for key, item in value.items() for text in _strings(key) + _strings(item)]
    if isinstance(value, (list, tuple)):
        return [text for item in value for text in _strings(item)]
    return [value] if isinstance(value, str) else []


def test_released_files_record_no_path_of_the_machine_that_made_them():
    for path in sorted(released_folder().iterdir()):
        if path.suffix == ".pt":
            texts = _strings({key: item for key, item in torch.load(path, weights_only=True).items()
                              if key != "state_dict"})
        else:
            texts = [path.read_text()]
        found = [match for text in texts for match in ABSOLUTE.findall(text)]
        assert not found, f"{path.name} records {found[:3]}"


def test_compiled_trees_score_as_lightgbm_does_bit_for_bit():
    """nbvtrain.ranking.trees against LightGBM itself: the released ranker's trees and a model with zero and
    NaN missing types, on rows with zeros, NaN and values on the thresholds."""
    from nbvtrain.ranking.trees import compile_trees

    rng = np.random.default_rng(1)
    head = json.loads((released_folder() / "viewrank.json").read_text())
    booster = lightgbm.Booster(model_str=head["lightgbm"])
    rows = (rng.random((400, booster.num_feature())) * rng.choice([0, 1, 5, 100], (400, booster.num_feature())))
    rows = rows.astype(np.float32)
    rows[rng.random(rows.shape) < 0.05] = 0
    rows[rng.random(rows.shape) < 0.02] = np.nan
    trees = compile_trees(head["lightgbm"])
    assert np.array_equal(trees.raw(rows), booster.predict(rows, num_threads=1, raw_score=True))
    features = rng.random((300, 4)).astype(np.float32)
    features[rng.random(features.shape) < 0.2] = 0
    features[rng.random(features.shape) < 0.1] = np.nan
    for zero_as_missing in (False, True):
        params = {"objective": "regression", "verbosity": -1, "num_threads": 1, "min_data_in_leaf": 3,
                  "zero_as_missing": zero_as_missing, "deterministic": True}
        model = lightgbm.train(params, lightgbm.Dataset(features, label=np.nan_to_num(features[:, 0]) * 3 + 1),
                               num_boost_round=15)
        trees = compile_trees(model.model_to_string())
        assert np.array_equal(trees.raw(features), model.predict(features, num_threads=1, raw_score=True))
