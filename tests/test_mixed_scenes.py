"""Training data is one scene: fit, baselines and the Dataset class refuse shards made with other
views, sensor or grid (naming the first differing setting and the two shards) unless mixing is
asked for, and a network trained on mixed scenes records so, which the scene checks honour."""

from pathlib import Path

import pytest
import torch
import yaml

from nbvdata.cli import main as nbvdata
from nbvdata.core.config import SimConfig, load_config, to_dict
from nbvdata.schema.shards import ShardError
from nbvtrain.cli import main as nbvtrain
from nbvtrain.networks.dataset import NBVDataset
from nbvtrain.networks.trained_scene import SceneMismatch, check_scene, scene_difference

ROOT = Path(__file__).resolve().parents[1]
SMOKE = str(ROOT / "configs" / "smoke.yaml")
FAST = ["--model", "nbvnet-3-3", "--batch-size", "8", "--threads", "1", "--no-progress"]


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict[str, Path]:
    """Smoke shards of three scenes: the smoke scene (60 views), 40 views, another sensor width."""
    root = tmp_path_factory.mktemp("scenes")
    settings = {"smoke": [], "views": ["--set", "views.count=40"], "sensor": ["--set", "sensor.width=40"]}
    for name, extra in settings.items():
        assert nbvdata(["generate", "--config", SMOKE, "--runs-per-mesh", "1", "--out", str(root / name),
                        "--no-progress", *extra]) == 0
    return {name: root / name for name in settings}


@pytest.mark.parametrize("other, key, values", [("views", "views.count", "40, not 60"),
                                                ("sensor", "sensor.width", "40, not 44")])
@pytest.mark.parametrize("command", ["fit", "baselines"])
def test_shards_of_two_scenes_are_refused_naming_the_setting_and_both_shards(scenes, other, key, values, command,
                                                                             tmp_path, capsys):
    run = tmp_path / "run"
    argv = [command, str(scenes["smoke"]), str(scenes[other])] + (["--epochs", "1", "--out", str(run), *FAST]
                                                                  if command == "fit" else [])
    assert nbvtrain(argv) == 2
    err = capsys.readouterr().err.strip()
    first, second = sorted(scenes["smoke"].glob("*.h5"))[0], sorted(scenes[other].glob("*.h5"))[0]
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert f"{second} was made in another scene than {first} ({key} {values})" in err and "--mixed-scenes" in err
    assert not run.exists()  # nothing written


def test_mixed_scenes_train_when_asked_and_the_checkpoint_says_so(scenes, tmp_path):
    run = tmp_path / "run"
    assert nbvtrain(["fit", str(scenes["smoke"]), str(scenes["views"]), "--mixed-scenes", "--epochs", "1",
                     "--out", str(run), *FAST]) == 0
    scene = torch.load(run / "best.pt", weights_only=True)["scene"]
    assert scene["mixed"] is True and scene["views_count"] == [40, 60] and scene["grid_size"] == [32]
    assert yaml.safe_load((run / "config.yaml").read_text())["mixed_scenes"] is True
    assert nbvtrain(["fit", "--resume", "--epochs", "2", "--out", str(run), "--no-progress"]) == 0  # recorded
    # the scene checks (evaluate's planners) accept either scene it was trained in, and no other
    for count in (40, 60):
        check_scene(scene, load_config(SimConfig, SMOKE, [f"views.count={count}"]), run / "best.pt")
    with pytest.raises(SceneMismatch, match=r"views_count 40 or 60 in its mixed scenes \(the run has 500\)"):
        check_scene(scene, SimConfig(), run / "best.pt")
    assert nbvtrain(["baselines", str(scenes["smoke"]), str(scenes["sensor"]), "--mixed-scenes"]) == 0


def test_shards_of_one_scene_mix_whatever_their_runs(scenes, tmp_path):
    """Rounds of one scene differ in ``episode`` only (more runs, exploration, a policy), and in
    whether they keep clouds (``state``; a round rolled without them adds to a version with them):
    one scene."""
    smoke = to_dict(load_config(SimConfig, SMOKE))
    rounds = to_dict(load_config(SimConfig, SMOKE, ["episode.runs_per_mesh=7", "episode.explore=0.25"]))
    assert scene_difference(smoke, rounds) is None
    assert scene_difference(smoke, to_dict(load_config(SimConfig, SMOKE, ["state.points=1024"]))) is None
    older = {section: dict(values) for section, values in smoke.items()}
    del older["coverage"]["metric"]  # a setting added later reads as its default
    assert scene_difference(smoke, older) is None
    imported = {"grid": {"size": 32}, "views": {"count": 60, "radius": 0.4}, "note": "imported"}
    assert scene_difference(smoke, imported)[0] == "mesh.object_size"
    assert scene_difference(smoke, to_dict(load_config(SimConfig, SMOKE, ["oracle.min_overlap=0.3"]))) == (
        "oracle.min_overlap", 0.2, 0.3)


def test_the_dataset_class_applies_the_same_rule(scenes):
    with pytest.raises(ShardError, match="views.count 40, not 60"):
        NBVDataset([scenes["smoke"], scenes["views"]])
    mixed = NBVDataset([scenes["smoke"], scenes["views"]], mixed_scenes=True)
    assert len(mixed) == len(NBVDataset(scenes["smoke"])) + len(NBVDataset(scenes["views"]))
