"""nbvtrain predict on untrusted input: checkpoints load as plain data only (a pickled object is
refused and runs nothing), anything else than a checkpoint or a grid in the authors' encoding is
a one-line error, and inference builds no deprecated torch.jit modules."""

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
import yaml

from nbvdata.core.config import SimConfig, to_yaml
from nbvdata.core.views import view_sphere
from nbvtrain.cli import main
from nbvtrain.networks.checkpoint import CheckpointError, load_checkpoint
from nbvtrain.networks.config import TrainConfig
from nbvtrain.networks.models import MODELS, build_model
from nbvtrain.networks.predict import GridError, Predictor
from nbvtrain.networks.train import save_training_state

ROOT = Path(__file__).resolve().parents[1]


def _checkpoint(path: Path, model: str = "nbvnet-3-3", history: list | None = None) -> Path:
    torch.manual_seed(0)
    units = view_sphere(SimConfig().views).unit_positions if MODELS[model].task == "scores" else None
    net = build_model(model, views=units)
    save_training_state(path, net, torch.optim.Adam(net.parameters()), TrainConfig(model=model), history or [], 0, 0.4, None, units)
    return path


class WritesAFile:
    """Unpickling this calls open(marker, "w"): code from the file would run and leave the marker."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return open, (str(self.marker), "w")


def _one_line_error(capsys, *expected: str) -> str:
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert all(text in err for text in expected), err
    return err


def test_checkpoints_are_plain_data(tmp_path):
    history = [{"epoch": np.int64(1), "train_loss": np.float64(0.5), "val_loss": np.float32(0.25)}]
    path = _checkpoint(tmp_path / "best.pt", history=history)
    state = torch.load(path, weights_only=True)  # raises if anything but plain data were in it
    assert state["history"] == [{"epoch": 1, "train_loss": 0.5, "val_loss": 0.25}]
    assert all(type(v) in (int, float) for v in state["history"][0].values())
    assert state["config"]["model"] == "nbvnet-3-3" and isinstance(state["view_radius"], float)
    assert Predictor(path).name == "nbvnet-3-3"


def test_a_pickled_object_is_refused_and_its_code_never_runs(tmp_path, capsys):
    marker = tmp_path / "ran"
    state = torch.load(_checkpoint(tmp_path / "good.pt"), weights_only=True)
    evil = tmp_path / "evil.pt"
    torch.save(state | {"history": [WritesAFile(marker)]}, evil)
    np.save(tmp_path / "grid.npy", np.full((32, 32, 32), 0.5, dtype=np.float32))
    with pytest.raises(CheckpointError, match=r"evil\.pt: holds a pickled Python object \(io\.open; not plain "
                       r"tensors\); refused without running it; pass a checkpoint"):
        Predictor(evil)
    assert main(["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(evil)]) == 2
    _one_line_error(capsys, str(evil), "refused", "nbvtrain fit")
    run = tmp_path / "run"  # the same as a run's last.pt: --resume refuses it too
    run.mkdir()
    (run / "config.yaml").write_text(to_yaml(TrainConfig(model="nbvnet-3-3")))
    evil.rename(run / "last.pt")
    assert main(["fit", "--resume", "--out", str(run), "--no-progress"]) == 2
    _one_line_error(capsys, str(run / "last.pt"), "refused", "another --out")
    assert not marker.exists()


def _junk(kind: str, path: Path) -> Path:
    if kind == "random bytes":
        path.write_bytes(np.random.default_rng(0).bytes(5000))
    elif kind == "text":
        path.write_text("model: nbvnet-4-5\nepochs: 600\n")
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "a folder":
        path.mkdir()
    elif kind == "a zip":
        import zipfile
        with zipfile.ZipFile(path, "w") as archive:
            archive.writestr("data.pkl", b"not a pickle")
    elif kind == "a tensor":
        torch.save(torch.zeros(3), path)
    elif kind == "no weights":
        torch.save({"model": "nbvnet-3-3", "epoch": 1, "config": {}}, path)
    elif kind == "unknown model":
        state = torch.load(_checkpoint(path), weights_only=True)
        torch.save(state | {"model": "resnet-50"}, path)
    elif kind == "other weights":  # nbvnet-3-5's weights under nbvnet-3-3's name
        state = torch.load(_checkpoint(path, "nbvnet-3-5"), weights_only=True)
        torch.save(state | {"model": "nbvnet-3-3"}, path)
    return path  # "missing": nothing written


JUNK = ["missing", "random bytes", "text", "empty", "a folder", "a zip", "a tensor", "no weights", "unknown model",
        "other weights"]


@pytest.mark.parametrize("kind", JUNK)
def test_anything_but_a_checkpoint_is_one_line_exit_2(kind, tmp_path, capsys):
    junk = _junk(kind, tmp_path / "junk.pt")
    with pytest.raises(CheckpointError, match=r"junk\.pt: .*; pass a checkpoint written by nbvtrain fit"):
        Predictor(junk)
    np.save(tmp_path / "grid.npy", np.full((32, 32, 32), 0.5, dtype=np.float32))
    assert main(["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(junk)]) == 2
    _one_line_error(capsys, f"nbvtrain predict: error: {junk}: ", "nbvtrain fit")


@pytest.mark.parametrize("kind", ["random bytes", "empty", "no weights", "other weights"])
def test_evaluate_and_resume_refuse_a_bad_checkpoint_in_one_line(kind, tmp_path, capsys):
    junk = _junk(kind, tmp_path / "junk.pt")
    meshes = tmp_path / "meshes"
    meshes.mkdir()
    trimesh.creation.box(extents=(0.1, 0.1, 0.1)).export(meshes / "box.stl")
    assert main(["evaluate", "--meshes", str(meshes), "--checkpoint", str(junk), "--planners", "regression",
                 "--out", str(tmp_path / "eval")]) == 2
    _one_line_error(capsys, f"nbvtrain evaluate: error: {junk}: ")
    assert not (tmp_path / "eval").exists()

    run = tmp_path / "run"
    run.mkdir()
    config = to_yaml(TrainConfig(model="nbvnet-3-3"))
    (run / "config.yaml").write_text(config)
    if kind == "other weights":  # a run of nbvnet-3-3 whose last.pt holds nbvnet-3-5's weights
        state = torch.load(_checkpoint(tmp_path / "other.pt", "nbvnet-3-5"), weights_only=True)
        torch.save(state | {"model": "nbvnet-3-3", "config": yaml.safe_load(config)}, run / "last.pt")
    else:
        junk.rename(run / "last.pt")
    before = {path.name: path.read_bytes() for path in run.iterdir()}
    assert main(["fit", "--resume", "--epochs", "5", "--out", str(run), "--no-progress"]) == 2
    _one_line_error(capsys, f"nbvtrain fit: error: {run / 'last.pt'}: ", "another --out")
    assert {path.name: path.read_bytes() for path in run.iterdir()} == before  # not even config.yaml rewritten


def test_a_device_torch_lacks_is_one_line(tmp_path, capsys):
    np.save(tmp_path / "grid.npy", np.full((32, 32, 32), 0.5, dtype=np.float32))
    checkpoint = _checkpoint(tmp_path / "best.pt")
    assert main(["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(checkpoint), "--device", "gpu7"]) == 2
    _one_line_error(capsys, "device 'gpu7': ", "use cpu")


def test_load_checkpoint_is_the_one_loader(tmp_path):
    """Predictor, evaluate's planners and fit --resume all read through load_checkpoint."""
    package = ROOT / "nbvtrain"
    modules = [package / "networks" / "predict.py", package / "networks" / "train.py",
               *sorted((package / "planners").glob("*.py")), package / "evaluation" / "evaluate.py",
               package / "cli.py", package / "commands.py"]
    for module in modules:
        assert "torch.load(" not in module.read_text(), module
    state = load_checkpoint(_checkpoint(tmp_path / "best.pt"))
    assert state["model"] == "nbvnet-3-3" and state["epoch"] == 0


BAD_GRIDS = {
    "all NaN": (np.full((32, 32, 32), np.nan, dtype=np.float32), r"holds 32768 NaN values"),
    "one NaN": (np.where(np.arange(32 ** 3) == 5, np.nan, 0.5).reshape(32, 32, 32), r"holds 1 NaN values"),
    "7.0": (np.full((32, 32, 32), 7.0), r"values in \[7, 7\], outside \[0, 1\]"),
    "negative": (np.full((32, 32, 32), -0.1), r"values in \[-0.1, -0.1\], outside \[0, 1\]"),
    "integers": (np.ones((32, 32, 32), dtype=np.int64), r"dtype int64, expected float occupancy probabilities"),
    "booleans": (np.ones((32, 32, 32), dtype=bool), r"dtype bool, expected float"),
    "16^3": (np.full((16, 16, 16), 0.5), r"shape \(16, 16, 16\), expected \(32, 32, 32\) or \(B, 32, 32, 32\)"),
    "flat": (np.full(32 ** 3, 0.5), r"shape \(32768,\)"),
}


@pytest.mark.parametrize("case", BAD_GRIDS)
def test_grids_outside_the_authors_encoding_are_refused(case, tmp_path, capsys):
    grid, message = BAD_GRIDS[case]
    predictor = Predictor(_checkpoint(tmp_path / "best.pt"))
    with pytest.raises(GridError, match=message):  # a ValueError
        predictor.predict(grid)
    np.save(tmp_path / "grid.npy", grid)  # the command line refuses what the API refuses, in one line
    assert main(["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(tmp_path / "best.pt")]) == 2
    _one_line_error(capsys, f"nbvtrain predict: error: {tmp_path / 'grid.npy'}: ")
    assert isinstance(GridError("x"), ValueError)


def test_the_edges_of_the_encoding_are_accepted(tmp_path):
    predictor = Predictor(_checkpoint(tmp_path / "best.pt"))
    grids = np.stack([np.zeros((32, 32, 32)), np.ones((32, 32, 32)), np.full((32, 32, 32), 0.5)]).astype(np.float16)
    assert len(predictor.predict(grids)) == 3


def test_predict_builds_no_torch_jit_and_warns_nothing(tmp_path):
    """torch.utils.mkldnn wraps each convolution in a deprecated torch.jit script module; the
    oneDNN path calls the same convolution directly, with the same outputs."""
    checkpoint = _checkpoint(tmp_path / "best.pt", "nbvnet-4-5")
    grid = np.random.default_rng(0).choice(np.array([0.4, 0.5, 0.7], dtype=np.float32), size=(32, 32, 32))
    np.save(tmp_path / "grid.npy", grid)
    script = ("import sys; from nbvtrain.cli import main; code = main(sys.argv[1:]); "
              "assert 'torch.utils.mkldnn' not in sys.modules, 'torch.jit modules built'; sys.exit(code)")
    done = subprocess.run([sys.executable, "-W", "error", "-c", script, "predict", str(tmp_path / "grid.npy"),
                           "--checkpoint", str(checkpoint)], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    predictor = Predictor(checkpoint)
    assert torch.backends.mkldnn.is_available() == (predictor._features is not predictor.model.features)
    with torch.inference_mode():
        grids = torch.from_numpy(grid)[None, None]
        torch.testing.assert_close(predictor._features(grids), predictor.model.features(grids), atol=1e-6, rtol=0)


# ---- the command line takes what the Python API takes -------------------------------------------------------


def _strict_json(text: str):
    """json.loads that refuses NaN and Infinity, which are not JSON."""
    import json

    def refuse(constant):
        raise ValueError(f"non-standard JSON constant {constant}")

    return json.loads(text, parse_constant=refuse)


@pytest.mark.parametrize("shape", [(64, 32, 16), (32, 1024), (32 ** 3,), (8, 64, 64), (2, 32, 32, 32, 1)])
def test_predict_refuses_what_the_api_refuses_whatever_the_number_of_values(shape, tmp_path, capsys):
    checkpoint = _checkpoint(tmp_path / "best.pt")
    grid = np.full(shape, 0.5, dtype=np.float32)
    with pytest.raises(GridError, match=r"expected \(32, 32, 32\) or \(B, 32, 32, 32\)"):
        Predictor(checkpoint).predict(grid)
    np.save(tmp_path / "grid.npy", grid)
    assert main(["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(checkpoint)]) == 2
    _one_line_error(capsys, f"nbvtrain predict: error: {tmp_path / 'grid.npy'}: grid has shape {shape}, expected "
                    "(32, 32, 32) or (B, 32, 32, 32)")


@pytest.mark.parametrize("model", ["nbvnet-3-3", "nbvscore-3"])
def test_predict_answers_a_batch_of_grids_with_a_list(model, tmp_path, capsys):
    """(B, 32, 32, 32) -> a JSON list of B answers, each the answer for that grid alone."""
    checkpoint = _checkpoint(tmp_path / "best.pt", model)
    rng = np.random.default_rng(0)
    grids = rng.choice(np.array([0.2, 0.5, 0.9], dtype=np.float32), size=(3, 32, 32, 32))
    np.save(tmp_path / "grids.npy", grids)
    assert main(["predict", str(tmp_path / "grids.npy"), "--checkpoint", str(checkpoint)]) == 0
    answers = _strict_json(capsys.readouterr().out)
    assert isinstance(answers, list) and len(answers) == 3
    predictor = Predictor(checkpoint)
    batch = predictor.predict(grids)  # the API's answers for the batch, exactly
    for index, answer in enumerate(answers):
        assert answer["source"] == f"{tmp_path / 'grids.npy'}[{index}]"
        assert answer["network_output"] == batch[index].raw.tolist() and answer["position"] == batch[index].to_dict()[
            "position"]
        np.save(tmp_path / "one.npy", grids[index])
        assert main(["predict", str(tmp_path / "one.npy"), "--checkpoint", str(checkpoint)]) == 0
        alone = _strict_json(capsys.readouterr().out)
        assert isinstance(alone, dict) and alone["source"] == str(tmp_path / "one.npy")  # one grid: one answer
        assert alone.keys() == answer.keys() and alone.get("view") == answer.get("view")
        for key in ("position", "direction", "network_output", "yaw", "pitch", "roll"):  # batched float32 sums
            assert answer[key] == pytest.approx(alone[key], rel=1e-5, abs=1e-6), key
    if model == "nbvscore-3":  # --scanned holds for every grid of the batch
        assert main(["predict", str(tmp_path / "grids.npy"), "--checkpoint", str(checkpoint), "--scanned", "1,2"]) == 0
        assert [a["scanned"] for a in _strict_json(capsys.readouterr().out)] == [[1, 2]] * 3


@pytest.mark.parametrize("option, value", [("--k", "0"), ("--k", "-2.5"), ("--k", "nan"), ("--k", "inf"),
                                           ("--radius", "0"), ("--radius", "-0.4"), ("--radius", "nan"),
                                           ("--radius", "abc")])
def test_k_and_radius_are_positive_finite_numbers(option, value, tmp_path, capsys):
    checkpoint = _checkpoint(tmp_path / "best.pt")
    np.save(tmp_path / "grid.npy", np.full((32, 32, 32), 0.5, dtype=np.float32))
    with pytest.raises(SystemExit) as done:
        main(["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(checkpoint), f"{option}={value}"])
    assert done.value.code == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert captured.out == "" and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith(f"nbvtrain predict: error: argument {option}: ") and "positive" in err, err


def test_the_python_api_refuses_a_scale_that_is_no_length(tmp_path):
    from nbvdata.core.config import ConfigError

    checkpoint = _checkpoint(tmp_path / "best.pt")
    for k, radius in ((float("nan"), None), (0.0, None), (1.0, -0.4), (1.0, float("inf"))):
        with pytest.raises(ConfigError, match="must be a positive finite number"):
            Predictor(checkpoint, k=k, radius=radius)
    state = torch.load(checkpoint, weights_only=True)  # a checkpoint's own view radius is checked too
    torch.save(state | {"view_radius": float("nan")}, tmp_path / "nan.pt")
    with pytest.raises(ConfigError, match="view radius nan"):
        Predictor(tmp_path / "nan.pt")


def test_the_printed_json_is_standard(tmp_path, capsys):
    checkpoint = _checkpoint(tmp_path / "best.pt")
    np.save(tmp_path / "grid.npy", np.full((32, 32, 32), 0.5, dtype=np.float32))
    assert main(["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(checkpoint), "--k", "2.5"]) == 0
    answer = _strict_json(capsys.readouterr().out)
    assert answer["k"] == 2.5 and np.linalg.norm(answer["position"]) == pytest.approx(2.5 * 0.4)


def test_every_json_the_package_writes_refuses_nan():
    """json.dumps(..., allow_nan=False) wherever the package prints or writes JSON."""
    import ast

    calls = 0
    for path in sorted((ROOT / "nbvdata").rglob("*.py")) + sorted((ROOT / "nbvtrain").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr in ("dump", "dumps") and isinstance(node.func.value, ast.Name)
                    and node.func.value.id == "json"):
                calls += 1
                strict = [k for k in node.keywords if k.arg == "allow_nan" and isinstance(k.value, ast.Constant)
                          and k.value.value is False]
                assert strict, f"{path.name}:{node.lineno}: json.{node.func.attr} without allow_nan=False"
    assert calls >= 8  # the walk found the package's JSON


# ---- checkpoint refusals say what the file is ----------------------------------------------------------------


def test_a_text_file_is_not_a_pytorch_checkpoint(tmp_path, capsys):
    """'j' is a pickle opcode: torch once read 'just ...' as a memo key (KeyError: 544502645)."""
    path = tmp_path / "notes.pt"
    path.write_text("just a note about the run\n")
    with pytest.raises(CheckpointError) as refused:
        load_checkpoint(path)
    assert str(refused.value) == (f"{path}: not a PyTorch checkpoint (a text file); pass a checkpoint written by "
                                  "nbvtrain fit (runs/NAME/best.pt)")


@pytest.mark.parametrize("protocol", [2, 4, 5])
def test_a_pickle_holding_an_object_is_refused_in_a_whole_sentence(protocol, tmp_path, capsys):
    import pickle

    marker = tmp_path / "ran"
    path = tmp_path / "evil.pt"
    with path.open("wb") as handle:
        pickle.dump({"model": "nbvnet-3-3", "history": [WritesAFile(marker)]}, handle, protocol=protocol)
    with pytest.raises(CheckpointError) as refused, warnings.catch_warnings(record=True) as warned:
        warnings.simplefilter("always")
        load_checkpoint(path)
    assert not warned, [str(w.message) for w in warned]  # the one line is all the command prints
    assert str(refused.value) == (f"{path}: holds a pickled Python object (io.open; not plain tensors); refused "
                                  "without running it; pass a checkpoint written by nbvtrain fit (runs/NAME/best.pt)")
    assert not marker.exists()


def test_a_pickle_of_plain_data_is_not_a_pytorch_checkpoint(tmp_path):
    import pickle

    path = tmp_path / "plain.pt"
    path.write_bytes(pickle.dumps({"model": "nbvnet-3-3", "epoch": 3}))
    with pytest.raises(CheckpointError, match=r"plain\.pt: not a PyTorch checkpoint \(a Python pickle, not written "
                       r"by torch\.save\)"):
        load_checkpoint(path)


@pytest.mark.parametrize("kind", JUNK + ["cut short"])
def test_no_refusal_suggests_loading_unsafely_or_stops_mid_word(kind, tmp_path):
    path = tmp_path / "junk.pt"
    if kind == "cut short":
        whole = _checkpoint(tmp_path / "whole.pt").read_bytes()
        path.write_bytes(whole[: len(whole) // 2])
    else:
        _junk(kind, path)
    with pytest.raises(CheckpointError) as refused:
        Predictor(path)
    message = str(refused.value)
    assert "weights_only" not in message and "allow" not in message and "Weights only load failed" not in message
    assert message.endswith("; pass a checkpoint written by nbvtrain fit (runs/NAME/best.pt)")
    assert message.count("(") == message.count(")"), message  # nothing cut off inside a bracket


# ---- .npy files that are not plain arrays ---------------------------------------------------------------------


class Marks:
    """An object whose unpickling would create ``marker``."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return open, (str(self.marker), "w")


def _npy(kind: str, path: Path) -> Path:
    if kind == "text":
        path.write_text("0.5 0.5 0.5\n")
    elif kind == "a pickle":
        import pickle

        path.write_bytes(pickle.dumps(np.full((32, 32, 32), 0.5)))
    elif kind == "an object array":
        array = np.empty(2, dtype=object)
        array[:] = [Marks(path.with_name("ran")), 1]
        np.save(path, array, allow_pickle=True)
    elif kind == "an npz":
        with path.open("wb") as handle:
            np.savez(handle, a=np.zeros(3), b=np.ones(3))
    elif kind == "cut short":
        np.save(path, np.full((32, 32, 32), 0.5, dtype=np.float32))
        path.write_bytes(path.read_bytes()[:5000])
    elif kind == "empty":
        path.write_bytes(b"")
    return path


NPY_JUNK = {"text": "not a numpy array file (.npy)", "a pickle": "not a numpy array file (.npy)",
            "an object array": "holds Python objects (a pickled object array); refused without unpickling it",
            "an npz": "holds several arrays (an .npz archive)", "cut short": "a .npy file, damaged or cut short",
            "empty": "not a numpy array file (.npy)"}


@pytest.mark.parametrize("kind", NPY_JUNK)
def test_predict_names_a_file_that_is_no_plain_array_and_never_unpickles_it(kind, tmp_path, capsys):
    checkpoint = _checkpoint(tmp_path / "best.pt")
    path = _npy(kind, tmp_path / "grid.npy")
    assert main(["predict", str(path), "--checkpoint", str(checkpoint)]) == 2
    err = _one_line_error(capsys, f"nbvtrain predict: error: {path}: {NPY_JUNK[kind]}")
    assert "allow_pickle" not in err and "pickle=" not in err
    assert not (tmp_path / "ran").exists()


def test_predict_says_what_a_file_that_is_no_grid_and_no_shard_is_not(tmp_path, capsys):
    """Issue 58: any file but a .npy (a text file, an array's raw bytes) was "not a readable HDF5
    file (truncated or corrupt?): delete it and run nbvdata generate again". It is told what it
    is not and what it is, and deleting is the fix only for an HDF5 file that is damaged; a .npy
    array under another name is read as the grid it is."""
    import h5py

    checkpoint = _checkpoint(tmp_path / "best.pt")
    grid = np.full((32, 32, 32), 0.5, dtype=np.float32)
    for name, data, kind in (("notes.txt", b"scanned the mug twice\n", "a text file"),
                             ("grid.bin", grid.tobytes(), "other bytes"), ("notes.h5", b"not a shard\n", "a text file"),
                             ("empty.h5", b"", "an empty file")):
        (tmp_path / name).write_bytes(data)
        assert main(["predict", str(tmp_path / name), "--checkpoint", str(checkpoint)]) == 2
        err = _one_line_error(capsys, f"{tmp_path / name}: not a shard (.h5) or a .npy grid ({kind}): ", "np.save")
        assert "delete" not in err and "HDF5" not in err, err
    with (tmp_path / "saved.bin").open("wb") as handle:
        np.save(handle, grid)
    assert main(["predict", str(tmp_path / "saved.bin"), "--checkpoint", str(checkpoint)]) == 0
    assert '"position"' in capsys.readouterr().out
    with h5py.File(tmp_path / "cut.h5", "w") as shard:
        shard["grids"] = np.zeros((64, 32, 32, 32), dtype=np.uint8)
    (tmp_path / "cut.h5").write_bytes((tmp_path / "cut.h5").read_bytes()[:100_000])
    assert main(["predict", str(tmp_path / "cut.h5"), "--checkpoint", str(checkpoint)]) == 2
    _one_line_error(capsys, f"{tmp_path / 'cut.h5'}: not a readable HDF5 file (truncated or corrupt?): delete it")


@pytest.mark.parametrize("grid, message", [
    (np.full((16, 16, 16), 0.5, dtype=np.float32), "grid has shape (16, 16, 16)"),
    (np.where(np.arange(32 ** 3).reshape(32, 32, 32) == 7, np.nan, 0.5).astype(np.float32), "1 NaN values"),
    (np.linspace(0, 3, 32 ** 3, dtype=np.float32).reshape(32, 32, 32), "outside [0, 1]"),
])
def test_the_ranker_checks_its_grids_as_a_network_does(tmp_path, capsys, grid, message):
    """The released ranker is predict's default: the same one-line refusals as the score network's."""
    np.save(tmp_path / "grid.npy", grid)
    assert main(["predict", str(tmp_path / "grid.npy")]) == 2
    _one_line_error(capsys, message)


def test_the_ranker_answers_each_of_several_grids(tmp_path, capsys):
    grids = np.full((3, 32, 32, 32), 0.5, dtype=np.float32)
    grids[1, 20:, :, :] = 0.1192
    grids[1, 19, 8:24, 8:24] = 0.971
    np.save(tmp_path / "one.npy", grids[1])
    assert main(["predict", str(tmp_path / "one.npy")]) == 0
    one = json.loads(capsys.readouterr().out)
    np.save(tmp_path / "grids.npy", grids)
    assert main(["predict", str(tmp_path / "grids.npy"), "--scanned", "1,2"]) == 0
    answers = json.loads(capsys.readouterr().out)
    assert [answer["source"] for answer in answers] == [f"{tmp_path / 'grids.npy'}[{i}]" for i in range(3)]
    assert all(answer["scanned"] == [1, 2] and answer["view"] not in (1, 2) for answer in answers)
    assert one["model"] == "viewrank-gbm" and one["scanned"] == []
