"""nbvtrain on smoke shards: the run folder, exact resume, Ctrl-C, augmentation, splits,
lazy loading, prediction and the baselines (the metrics: test_metrics.py)."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from nbvdata.cli import main as nbvdata_main
from nbvdata.core.views import farthest_view
from nbvdata.schema.shards import Shard, ShardError
from nbvdata.simulation.grid import OccupancyGrid
from nbvtrain.cli import main
from nbvtrain.networks.baselines import Skipped, farthest, mean_direction, mean_vector, nearest_neighbour_indices
from nbvtrain.networks.checkpoint import save_checkpoint
from nbvtrain.networks.predict import Predictor
from nbvtrain.networks.train import _StopOnCtrlC, _StopRequested
from nbvtrain.networks.training_data import load_shards, load_view_states, rotate_quarter_turns, split_indices

ROOT = Path(__file__).resolve().parents[1]
FAST = ["--model", "nbvnet-3-3", "--batch-size", "16", "--threads", "1", "--no-progress"]


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("smoke") / "shards"
    assert nbvdata_main(["generate", "--config", str(ROOT / "configs" / "smoke.yaml"), "--out", str(out),
                         "--no-progress"]) == 0
    return out


def _weights(run: Path) -> dict[str, torch.Tensor]:
    return torch.load(run / "last.pt", weights_only=True)["state_dict"]


def test_fit_writes_a_complete_run_folder(shards, tmp_path):
    run = tmp_path / "run"
    assert main(["fit", str(shards), "--epochs", "2", "--out", str(run), *FAST]) == 0
    assert {p.name for p in run.iterdir()} >= {"config.yaml", "data.json", "metrics.csv", "curves.png",
                                               "last.pt", "best.pt"}
    rows = (run / "metrics.csv").read_text().splitlines()
    assert rows[0].split(",")[:7] == ["epoch", "train_loss", "val_loss", "val_mse", "val_mae", "val_angle_deg",
                                      "val_gain_ratio"]
    assert len(rows) == 3
    checkpoint = torch.load(run / "best.pt", weights_only=True)
    assert checkpoint["model"] == "nbvnet-3-3" and checkpoint["config"]["batch_size"] == 16
    for row in checkpoint["history"]:
        assert 0 < row["val_gain_ratio"] <= 1 and 0 <= row["val_angle_deg"] <= 180
        assert row["val_mse"] == pytest.approx(row["val_loss"])
        assert row["machine"].startswith("cpu: ") and row["machine"].endswith("(1 thread)")  # FAST: --threads 1
    assert rows[0].endswith(",machine") and rows[1].endswith("(1 thread)")
    data = json.loads((run / "data.json").read_text())
    assert data["train_samples"] + data["val_samples"] == data["samples"] == 72
    assert (run / "config.yaml").read_text().startswith("model: nbvnet-3-3")


def test_resume_continues_exactly_like_an_uninterrupted_run(shards, tmp_path):
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    assert main(["fit", str(shards), "--epochs", "3", "--augment", "--out", str(straight), *FAST]) == 0
    assert main(["fit", str(shards), "--epochs", "2", "--augment", "--out", str(resumed), *FAST]) == 0
    assert main(["fit", "--resume", "--epochs", "3", "--out", str(resumed), "--no-progress"]) == 0
    a, b = _weights(straight), _weights(resumed)
    assert all(torch.equal(a[key], b[key]) for key in a)
    assert (straight / "metrics.csv").read_text().splitlines()[1:] != []
    strip = lambda path: [line.split(",")[:7] for line in path.read_text().splitlines()]  # noqa: E731
    assert strip(straight / "metrics.csv") == strip(resumed / "metrics.csv")


def test_user_errors_exit_2_with_one_line(shards, tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["fit", "--out", str(run)]) == 2
    assert main(["fit", "--resume", "--out", str(tmp_path / "none")]) == 2
    assert main(["fit", str(tmp_path / "missing"), "--out", str(run)]) == 2
    assert main(["fit", str(shards), "--epochs", "1", "--out", str(run), *FAST]) == 0
    assert main(["fit", str(shards), "--epochs", "1", "--out", str(run), *FAST]) == 2
    assert main(["fit", "--resume", "--model", "nbvnet-4-5", "--out", str(run)]) == 2
    assert main(["fit", str(shards), "--set", "dropuot=0.1", "--out", str(tmp_path / "x")]) == 2
    assert main(["fit", str(shards), "--split", "mesh", "--val-fraction", "0.2", "--epochs", "1",
                 "--out", str(tmp_path / "mesh"), *FAST]) == 0
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(errors) == 6
    assert "no shards given" in errors[0] and "no run to resume" in errors[1]
    assert "no such shard" in errors[2] and "add --resume" in errors[3]
    assert "only --epochs may change" in errors[4] and "did you mean 'dropout'" in errors[5]


def test_bad_input_leaves_no_run_folder_behind(shards, tmp_path, capsys):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "junk.h5").write_bytes(b"not an HDF5 file" * 100)
    run = tmp_path / "run"
    assert main(["fit", str(bad), "--epochs", "1", "--out", str(run), *FAST]) == 2
    assert "junk.h5: not an HDF5 file (a text file), so not a shard" in capsys.readouterr().err
    assert not run.exists()
    if not torch.cuda.is_available():
        assert main(["fit", str(shards), "--device", "cuda", "--epochs", "1", "--out", str(run), *FAST]) == 2
        assert "torch sees no GPU" in capsys.readouterr().err and not run.exists()
    mine = tmp_path / "mine"  # a folder the user made: what is in it stays, and nothing is added
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    assert main(["fit", str(bad), "--epochs", "1", "--out", str(mine), *FAST]) == 2
    assert [p.name for p in mine.iterdir()] == ["notes.txt"] and (mine / "notes.txt").read_text() == "keep me"
    (tmp_path / "file.txt").write_text("keep me")
    assert main(["fit", str(shards), "--epochs", "1", "--out", str(tmp_path / "file.txt"), *FAST]) == 2
    assert "a file, not a folder" in capsys.readouterr().err and (tmp_path / "file.txt").read_text() == "keep me"


def test_help_ends_in_whole_sentences(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    description = capsys.readouterr().out.split("\n\n")[1]
    assert description.rstrip().endswith(".") and "closed-loop" in description, description


# 0.1-0.2 s after the first last.pt, fit is importing matplotlib for curves.png: a KeyboardInterrupt
# raised inside a dataclass built by exec() there made `python -m nbvtrain` die by SIGINT (-2).
@pytest.mark.parametrize("delay", [0.1, 0.2, 0.6])
def test_ctrl_c_saves_a_checkpoint_that_resumes(shards, tmp_path, delay):
    run = tmp_path / "run"
    # A runner started in the background (nohup ... &) passes SIGINT on as ignored, and Python then
    # never raises KeyboardInterrupt: give the child the default disposition, as a terminal would.
    process = subprocess.Popen([sys.executable, "-m", "nbvtrain", "fit", str(shards), "--epochs", "100000",
                                "--out", str(run), *FAST], stderr=subprocess.PIPE, text=True,
                               env=dict(os.environ, PYTHONUNBUFFERED="1"),
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 120
    while not (run / "last.pt").exists() and time.time() < deadline:
        time.sleep(0.01)
    time.sleep(delay)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "continue with: nbvtrain fit --resume" in err
    done = torch.load(run / "last.pt", weights_only=True)["epoch"]
    assert done >= 1
    assert main(["fit", "--resume", "--epochs", str(done + 1), "--out", str(run), "--no-progress"]) == 0
    assert len((run / "metrics.csv").read_text().splitlines()) == done + 2


@pytest.mark.parametrize("stop_at", [2, 6, 9])
def test_ctrl_c_inside_an_epoch_then_resume_is_the_uninterrupted_run_bit_for_bit(shards, tmp_path, monkeypatch,
                                                                                 stop_at):
    """A real SIGINT after the stop_at-th batch boundary check (4 batches an epoch here, and one
    check after each epoch's end): inside epoch 1, inside epoch 2, at an epoch's last batch. The
    resumed run ends with the weights, optimiser state and losses of the run never stopped."""
    import nbvtrain.networks.train as train

    args = ["--epochs", "3", "--augment", "--dropout", "0.5", *FAST]
    straight, stopped = tmp_path / "straight", tmp_path / "stopped"
    assert main(["fit", str(shards), "--out", str(straight), *args]) == 0
    calls, check = [0], train._StopOnCtrlC.check

    def interrupt_once(stop):
        calls[0] += 1
        if calls[0] == stop_at:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # the handler runs between bytecodes of the main thread
        check(stop)

    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal
    try:
        monkeypatch.setattr(train._StopOnCtrlC, "check", interrupt_once)
        assert main(["fit", str(shards), "--out", str(stopped), *args]) == 130
    finally:
        signal.signal(signal.SIGINT, before)
    monkeypatch.undo()
    saved = torch.load(stopped / "last.pt", weights_only=True)
    if stop_at % 5:  # inside an epoch: its progress is saved
        assert saved["partial"]["batches"] == stop_at % 5 and saved["partial"]["epoch"] == stop_at // 5 + 1
    assert main(["fit", "--resume", "--out", str(stopped), "--no-progress"]) == 0
    a, b = (torch.load(run / "last.pt", weights_only=True) for run in (straight, stopped))
    assert all(torch.equal(a["state_dict"][key], b["state_dict"][key]) for key in a["state_dict"])
    assert all(torch.equal(x, y) for x, y in zip(_tensors(a["optimizer"]), _tensors(b["optimizer"])))
    strip = lambda path: [line.split(",")[:8] for line in path.read_text().splitlines()]  # noqa: E731
    assert strip(straight / "metrics.csv") == strip(stopped / "metrics.csv") and "partial" not in b


def _tensors(value) -> list[torch.Tensor]:
    """Every tensor in a nested state dict, in order."""
    if isinstance(value, torch.Tensor):
        return [value]
    if isinstance(value, dict):
        return [t for key in sorted(value, key=str) for t in _tensors(value[key])]
    if isinstance(value, (list, tuple)):
        return [t for item in value for t in _tensors(item)]
    return []


def test_a_loss_that_is_not_finite_stops_fit_in_one_line(shards, tmp_path, capsys, monkeypatch):
    """A learning rate that blows the weights up: exit 2 naming the epoch and batch, and nothing of
    that epoch saved (last.pt stays the last whole epoch's)."""
    run = tmp_path / "run"
    assert main(["fit", str(shards), "--epochs", "1", "--out", str(run), *FAST]) == 0
    import nbvtrain.networks.train as train

    real = train._regression_loss
    monkeypatch.setattr(train, "_regression_loss", lambda *a, **k: real(*a, **k) * float("nan"))
    before = (run / "last.pt").read_bytes()
    assert main(["fit", "--resume", "--epochs", "2", "--out", str(run), "--no-progress"]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "epoch 2, batch 1: the loss is nan" in error[0] and "lower --lr" in error[0]
    assert (run / "last.pt").read_bytes() == before


def test_first_ctrl_c_asks_fit_to_stop_and_a_second_interrupts_at_once():
    # Python's own handler, as in a terminal (a runner started with & ignores SIGINT: fit leaves that alone)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _check_stop_on_ctrl_c()
    finally:
        signal.signal(signal.SIGINT, before)


def _check_stop_on_ctrl_c():
    with _StopOnCtrlC() as stop:
        stop.check()  # nothing asked yet
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.01)  # the handler runs between bytecodes of the main thread
        assert stop.requested
        with pytest.raises(_StopRequested):
            stop.check()
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with _StopOnCtrlC() as stop:
        assert stop._previous is None  # SIGINT ignored (nohup, a runner in the background): left ignored
    outcome = {}
    thread = threading.Thread(target=lambda: outcome.update(handler=_StopOnCtrlC().__enter__()._previous))
    thread.start()
    thread.join()
    assert outcome == {"handler": None}  # only the main thread may set one: leave SIGINT alone there


def test_quarter_turns_rotate_grid_and_target_together(rng):
    centres = OccupancyGrid().voxel_centres()
    for _ in range(20):
        voxel = tuple(rng.integers(0, 32, 3))
        codes = np.zeros((1, 32, 32, 32), dtype=np.uint8)
        codes[(0, *voxel)] = 1
        target = centres[voxel][None].astype(np.float32)
        for turns in range(4):
            rotated, moved = rotate_quarter_turns(codes, target, np.array([turns]))
            (where,) = np.argwhere(rotated[0] == 1)
            np.testing.assert_allclose(centres[tuple(where)], moved[0], atol=1e-7)
            assert rotated.sum() == 1
    assert rotate_quarter_turns(codes, target, np.array([0]))[0] is not codes  # inputs untouched


def test_splits_are_seeded_disjoint_and_object_disjoint(shards):
    data = load_shards([*sorted(shards.glob("*.h5"))])
    try:
        train, val, _ = split_indices(data, "random", 0.2, seed=3)
        assert len(np.intersect1d(train, val)) == 0 and len(train) + len(val) == len(data)
        assert np.array_equal(split_indices(data, "random", 0.2, seed=3)[1], val)
        assert not np.array_equal(split_indices(data, "random", 0.2, seed=4)[1], val)
        train, val, info = split_indices(data, "mesh", 0.34, seed=3)
        assert len(info["val_meshes"]) == 2
        assert not set(data.mesh_ids[train]) & set(data.mesh_ids[val])
        assert set(data.mesh_ids[val]) == set(info["val_meshes"])
        with pytest.raises(ShardError, match="--val-fraction 0.99: .* hold out fewer meshes"):
            split_indices(data, "mesh", 0.99, seed=3)  # no mesh would be left to train on
    finally:
        data.close()


def test_lazy_loading_gives_the_same_grids_as_in_memory(shards, rng):
    paths = sorted(shards.glob("*.h5"))
    memory, lazy = load_shards(paths), load_shards(paths, memory_limit_gb=0)
    try:
        index = rng.permutation(len(memory))[:40]
        assert np.array_equal(memory.grids.take(index), lazy.grids.take(index))
        with Shard(paths[0]) as first, Shard(paths[1]) as shard:  # both decode to the shard's probabilities
            start = len(first)
            np.testing.assert_array_equal(memory.palette[memory.grids.take(np.array([start]))][0], shard.grids(0))
    finally:
        memory.close()
        lazy.close()


def test_predict_gives_a_look_at_pose_at_the_scaled_radius(shards, tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["fit", str(shards), "--epochs", "1", "--out", str(run), *FAST]) == 0
    capsys.readouterr()
    shard = sorted(shards.glob("*.h5"))[0]
    assert main(["predict", str(shard), "--index", "2", "--checkpoint", str(run / "best.pt"), "--k", "2.5"]) == 0
    result = json.loads(capsys.readouterr().out)
    position = np.array(result["position"])
    assert np.linalg.norm(position) == pytest.approx(0.4 * 2.5)
    np.testing.assert_allclose(position / 1.0, np.array(result["direction"]), atol=1e-12)
    predictor = Predictor(run / "best.pt")
    with Shard(shard) as s:
        grid = s.grids(2)
    np.save(tmp_path / "grid.npy", grid)
    (prediction,) = predictor.predict(grid)
    np.testing.assert_allclose(prediction.pose.direction, -prediction.direction, atol=1e-12)  # looks at centre
    assert abs(prediction.pose.rotation[0, 2]) < 1e-12  # image rows horizontal: no spin about the axis
    np.testing.assert_allclose(prediction.direction, np.array(result["direction"]), atol=1e-6)
    assert main(["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(run / "best.pt")]) == 0
    assert main(["predict", str(shard), "--checkpoint", str(tmp_path / "nope.pt")]) == 2
    assert main(["predict", str(shard), "--index", "999", "--checkpoint", str(run / "best.pt")]) == 2


def test_classification_net_trains_on_the_same_shards(shards, tmp_path):
    run = tmp_path / "class"
    assert main(["fit", str(shards), "--epochs", "1", "--out", str(run), "--model", "nbvnet-class",
                 "--batch-size", "16", "--threads", "1", "--no-progress"]) == 0
    (prediction,) = Predictor(run / "best.pt").predict(np.full((32, 32, 32), 0.5, dtype=np.float32))
    assert np.linalg.norm(prediction.raw) == pytest.approx(1.0)  # one of the 14 class views


def test_baselines(shards):
    data = load_shards(sorted(shards.glob("*.h5")))
    try:
        train, val, _ = split_indices(data, "random", 0.2, seed=0)
        assert np.array_equal(nearest_neighbour_indices(data, train, train[:10]), train[:10])  # itself
        scores = mean_direction(data, train, val)
        assert 0 < scores["mse"] < 1 and 0 < scores["gain_ratio"] <= 1
        # on the training samples themselves the unscaled mean is the constant with the least MSE
        assert mean_vector(data, train, train)["mse"] <= mean_direction(data, train, train)["mse"]
        # the farthest view from the state's scans: a valid candidate view, never a scanned one (gain 0)
        spread = farthest(data, train, val)
        assert 0 < spread["gain_ratio"] <= 1 and spread["angle_deg"] > 0
        taken = load_view_states(data.paths, poses="nearest")[val]
        picks = [farthest_view(data.view_units, data.view_units[t]) for t in taken]
        assert not any(t[i] for t, i in zip(taken, picks))
        with pytest.raises(Skipped, match="no candidate views"):
            farthest(SimpleNamespace(view_units=None), train, val)
    finally:
        data.close()


SCORE = ["--model", "nbvscore-3", "--batch-size", "16", "--threads", "1", "--lr", "1e-3", "--no-progress"]


def test_a_score_network_trains_resumes_exactly_and_picks_unscanned_views(shards, tmp_path, capsys):
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    for run, epochs in ((straight, "3"), (resumed, "2")):
        assert main(["fit", str(shards), "--epochs", epochs, "--out", str(run), *SCORE]) == 0
    assert main(["fit", "--resume", "--epochs", "3", "--out", str(resumed), "--no-progress"]) == 0
    a, b = _weights(straight), _weights(resumed)
    assert all(torch.equal(a[key], b[key]) for key in a)
    checkpoint = torch.load(straight / "best.pt", weights_only=True)
    shard = sorted(shards.glob("*.h5"))[0]
    with Shard(shard) as s:
        last, step, run_key, views = s["last_view"], s["step"], s["run"], s["view_positions"]
    assert checkpoint["task"] == "scores" and checkpoint["view_units"].shape == views.shape
    np.testing.assert_allclose(checkpoint["view_units"].numpy() * 0.4, views, atol=1e-12)
    assert checkpoint["scene"]["views_count"] == len(views) and checkpoint["scene"]["grid_size"] == 32
    for row in checkpoint["history"]:
        assert 0 < row["val_gain_ratio"] <= 1 and row["val_loss"] > 0
    capsys.readouterr()
    later = int(np.flatnonzero(step >= 3)[0])  # a state with three scanned views
    scanned = sorted({int(v) for v in last[(run_key == run_key[later]) & (step <= step[later])]})
    assert main(["predict", str(shard), "--index", str(later), "--checkpoint", str(straight / "best.pt")]) == 0
    answer = json.loads(capsys.readouterr().out)
    assert answer["scanned"] == scanned and answer["view"] not in scanned and len(scanned) == 3
    assert main(["predict", str(shard), "--index", str(later), "--checkpoint", str(straight / "best.pt"),
                 "--scanned", f"0,1,{len(views) + 39}"]) == 2
    assert (f"--scanned: indices [{len(views) + 39}] out of range; the view set has {len(views)} views "
            f"(0..{len(views) - 1})") in capsys.readouterr().err


def test_only_a_score_network_with_views_as_inputs_turns(shards, tmp_path, capsys):
    fc = [*SCORE[2:], "--model", "nbvscore-fc3"]
    assert main(["fit", str(shards), "--epochs", "1", "--augment", "--out", str(tmp_path / "a"), *fc]) == 2
    assert "quarter turns do not map the candidate views" in capsys.readouterr().err
    assert main(["fit", str(shards), "--epochs", "1", "--augment", "--out", str(tmp_path / "b"), *SCORE]) == 0
    assert not (tmp_path / "a").exists()


def test_the_cosine_schedule_falls_from_lr_to_near_zero():
    from nbvtrain.networks.config import TrainConfig
    from nbvtrain.networks.train import learning_rate

    config = TrainConfig(lr=1e-3, epochs=10, lr_schedule="cosine")
    rates = [learning_rate(config, epoch) for epoch in range(1, 11)]
    assert rates[0] == 1e-3 and all(a > b > 0 for a, b in zip(rates, rates[1:])) and rates[-1] < 3e-5
    assert learning_rate(TrainConfig(lr=1e-3, epochs=10), 7) == 1e-3


@pytest.mark.parametrize("name", ["nbvnet-4-3", "nbvscore-fc3"])
def test_channels_last_training_is_the_same_arithmetic_in_another_order(name):
    """fit lays grid networks out channels-last on the CPU for speed: the step must be the same
    sums in another order (equal to float32 rounding), and the layout must really change."""
    from nbvtrain.networks.models import build_model
    from nbvtrain.networks.train import _inputs, _memory_layout

    torch.manual_seed(0)
    views = np.eye(3)[np.arange(8) % 3] * np.where(np.arange(8) < 4, 1, -1)[:, None] if "score" in name else None
    plain = build_model(name, views=views)
    fast = _memory_layout(build_model(name, views=views), torch.device("cpu"))
    fast.load_state_dict(plain.state_dict())
    convolutions = [p for p in fast.parameters() if p.dim() == 5]
    assert convolutions and all(p.is_contiguous(memory_format=torch.channels_last_3d) for p in convolutions)
    codes = np.random.default_rng(0).integers(0, 3, (4, 32, 32, 32)).astype(np.uint8)
    palette = torch.tensor([0.12, 0.5, 0.97])
    grids = _inputs(codes, palette, "grid", torch.device("cpu"))
    assert grids.is_contiguous(memory_format=torch.channels_last_3d)
    taken = torch.zeros(len(codes), 8, dtype=torch.bool) if views is not None else None
    run = (lambda model, x: model(x, taken)) if views is not None else (lambda model, x: model(x))
    for model in (plain, fast):
        model.eval()  # no dropout: its masks are drawn in memory order, so they differ between layouts
        run(model, grids).square().mean().backward()
    for (layer, a), b in zip(plain.named_parameters(), fast.parameters()):
        scale = float(a.grad.abs().max())
        assert scale > 0, layer
        np.testing.assert_allclose(a.grad.numpy(), b.grad.numpy(), rtol=0, atol=1e-4 * scale, err_msg=layer)
    with torch.no_grad():
        np.testing.assert_allclose(run(plain, grids.contiguous()).numpy(), run(fast, grids).numpy(), rtol=1e-4,
                                   atol=1e-5)


def test_the_near_best_loss_trains_resumes_exactly_and_needs_gains(shards, tmp_path, capsys):
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    near = ["--regression-loss", "near-best", "--near-best", "0.8", "--augment", *FAST]
    assert main(["fit", str(shards), "--epochs", "2", "--out", str(straight), *near]) == 0
    assert main(["fit", str(shards), "--epochs", "1", "--out", str(resumed), *near]) == 0
    assert main(["fit", "--resume", "--epochs", "2", "--out", str(resumed), "--no-progress"]) == 0
    a, b = _weights(straight), _weights(resumed)
    assert all(torch.equal(a[key], b[key]) for key in a)
    checkpoint = torch.load(straight / "best.pt", weights_only=True)
    assert checkpoint["config"]["regression_loss"] == "near-best" and checkpoint["config"]["near_best"] == 0.8
    label = tmp_path / "label"
    assert main(["fit", str(shards), "--epochs", "2", "--augment", "--out", str(label), *FAST]) == 0
    assert not all(torch.equal(a[key], _weights(label)[key]) for key in a)  # another loss, other weights
    # the near-best validation loss is at most the label's squared error for the same output
    history = checkpoint["history"]
    assert all(row["val_loss"] <= row["val_mse"] + 1e-9 for row in history)
    # recipes/regression_answers.py reads the run's validation states and compares the two losses
    answers = subprocess.run([sys.executable, str(ROOT / "recipes" / "regression_answers.py"), str(straight),
                              str(straight / "best.pt"), str(label / "best.pt"), "--samples", "10"],
                             capture_output=True, text=True, check=True).stdout.splitlines()
    assert answers[0].startswith("10 validation states of") and len(answers) == 6
    for line in answers[2:5]:
        norm, ratio, resultant, views = (float(x) for x in line.split()[-4:])
        assert 0 <= norm <= 3 ** 0.5 and 0 <= ratio <= 1 and 0 <= resultant <= 1 and 1 <= views <= 10
    assert answers[4].split()[-3] == "1.000"  # the labels are the best views
    # imported data (no gains): refused before anything is written
    from nbvdata.datasets.authors import import_legacy
    directions = np.random.default_rng(0).normal(size=(6, 3))
    np.save(tmp_path / "volumes.npy", np.full((6, 32 ** 3), 0.5))
    units = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    np.save(tmp_path / "poses.npy", np.concatenate([0.4 * units, np.zeros((6, 3))], axis=1))
    import_legacy(tmp_path / "volumes.npy", tmp_path / "poses.npy", tmp_path / "imported", rows_per_shard=4,
                  show_progress=False)
    capsys.readouterr()
    assert main(["fit", str(tmp_path / "imported"), "--epochs", "1", "--out", str(tmp_path / "no"), *near]) == 2
    err = capsys.readouterr().err
    assert "regression_loss=near-best learns from every candidate view's gain" in err and "regression_loss=label" in err
    assert not (tmp_path / "no").exists()
    # a loss of the regression networks only
    assert main(["fit", str(shards), "--regression-loss", "near-best", "--out", str(tmp_path / "s"), *SCORE]) == 2
    assert ("regression_loss=near-best with nbvscore-3: a loss of the regression networks (nbvnet-3-3, "
            in capsys.readouterr().err)
    with pytest.raises(SystemExit) as stopped:
        main(["fit", str(shards), "--near-best", "0", "--out", str(tmp_path / "zero"), *FAST])
    assert stopped.value.code == 2 and "--near-best: must be a number in (0, 1]" in capsys.readouterr().err


def test_scan_closeness_turns_with_the_scans_and_matches_the_view_states(rng):
    from nbvtrain.networks.models import (SCAN_DIRECTIONS, quarter_turns, scan_closeness, turn_closeness,
                                          view_state_closeness)
    positions = rng.normal(size=(4, 3)) * 0.4
    closeness = scan_closeness(positions)
    assert closeness.shape == (len(SCAN_DIRECTIONS),) and closeness.dtype == np.float32
    assert np.all((closeness > 0) & (closeness <= 1))
    assert not scan_closeness(np.zeros((0, 3))).any()  # nothing scanned
    assert scan_closeness(SCAN_DIRECTIONS[7] * 2.5)[7] == 1.0  # a scan on a direction, at any radius
    for turns in range(4):  # scans turned as their grid: the same numbers, permuted
        turned = turn_closeness(closeness[None], np.array([turns]))[0]
        np.testing.assert_allclose(scan_closeness(quarter_turns(positions, turns)), turned, atol=1e-6)
        assert (turns == 0) == np.array_equal(turned, closeness)
    units = rng.normal(size=(30, 3))
    units /= np.linalg.norm(units, axis=1, keepdims=True)
    taken = rng.random((2000, 30)) < 0.2
    rows = view_state_closeness(taken, units)
    for i in (0, 1, 1500, 1999):  # across a chunk boundary
        assert np.array_equal(rows[i], scan_closeness(units[taken[i]]))


def test_a_network_told_the_scans_starts_as_the_one_it_widens_and_reads_them(shards, tmp_path, capsys):
    plain, told = tmp_path / "plain", tmp_path / "told"
    near = ["--regression-loss", "near-best", "--augment", "--batch-size", "16", "--threads", "1", "--no-progress"]
    assert main(["fit", str(shards), "--epochs", "1", "--out", str(plain), "--model", "nbvnet-4-3", *near]) == 0
    start = torch.load(plain / "best.pt", weights_only=True)
    assert main(["fit", str(shards), "--epochs", "1", "--out", str(told), "--model", "nbvnet-4-3-scans",
                 "--init", str(plain / "best.pt"), "--lr", "1e-9", *near]) == 0
    after = torch.load(told / "best.pt", weights_only=True)["state_dict"]
    fc1 = after["head.1.weight"]
    assert fc1.shape[1] == start["state_dict"]["head.1.weight"].shape[1] + 42
    assert fc1[:, -42:].abs().max() < 1e-6  # zero columns, moved by at most lr per step
    grid = np.full((32, 32, 32), 0.5, dtype=np.float32)
    grid[12:20, 12:20, 12:20] = 0.9
    scans = np.array([[0.4, 0.0, 0.0], [0.0, 0.0, 0.4]])
    widened = Predictor(told / "best.pt")
    np.testing.assert_allclose(widened.raw(grid, scans=scans), Predictor(plain / "best.pt").raw(grid), atol=1e-4)
    # the scans enter the answer; averaged over quarter turns, grid and scans turned together turn it
    averaged = Predictor(told / "best.pt", tta=True)
    with torch.no_grad():
        averaged.model.head[1].weight[:, -42:].normal_(0, 0.3, generator=torch.Generator().manual_seed(0))
    assert not np.allclose(averaged.raw(grid, scans=scans), averaged.raw(grid, scans=scans[:1]), atol=1e-3)
    grid[14:18, 20:24, 14:24] = 0.1  # no longer symmetric
    turned = np.ascontiguousarray(np.rot90(grid, 1, axes=(0, 1)))
    from nbvtrain.networks.models import quarter_turns
    answer = averaged.raw(grid, scans=scans)
    np.testing.assert_allclose(averaged.raw(turned, scans=quarter_turns(scans, 1)), quarter_turns(answer, 1),
                               atol=1e-5)
    assert not np.allclose(averaged.raw(turned, scans=scans), quarter_turns(answer, 1), atol=1e-3)
    # a network that reads no scans ignores them; another network than the one widened is refused
    assert np.array_equal(Predictor(plain / "best.pt").raw(grid, scans=scans), Predictor(plain / "best.pt").raw(grid))
    # predict on a .npy grid: the sensor positions from --scanned-at, required for this network
    checkpoint = torch.load(told / "best.pt", weights_only=True)
    checkpoint["state_dict"]["head.1.weight"][:, -42:] = averaged.model.head[1].weight[:, -42:]
    save_checkpoint(told / "perturbed.pt", checkpoint)  # weights changed on purpose: their checksum anew
    np.save(tmp_path / "grid.npy", grid)
    predict = ["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(told / "perturbed.pt")]
    capsys.readouterr()
    assert main(predict) == 2
    assert "reads where the sensor has been: pass --scanned-at" in capsys.readouterr().err
    perturbed = Predictor(told / "perturbed.pt")
    answers = []
    for text, positions in (("0.4,0,0;0,0,0.4", scans), ("0.4, 0, 0", scans[:1]), ("none", np.zeros((0, 3)))):
        assert main([*predict, "--scanned-at", text]) == 0
        answer = json.loads(capsys.readouterr().out)
        assert answer["scanned_at"] == positions.tolist()
        np.testing.assert_allclose(answer["position"], perturbed.predict(grid, scans=positions)[0].to_dict()["position"],
                                   atol=1e-6)
        answers.append(answer["network_output"])
    assert not np.allclose(answers[0], answers[1], atol=1e-4) and not np.allclose(answers[1], answers[2], atol=1e-4)
    assert main([*predict, "--scanned-at", "0.4,0;1,2,3"]) == 2
    assert "give the sensor positions as x,y,z;x,y,z" in capsys.readouterr().err
    assert main(["predict", str(tmp_path / "grid.npy"), "--checkpoint", str(plain / "best.pt"), "--scanned-at",
                 "0.4,0,0"]) == 2
    assert "reads no sensor positions" in capsys.readouterr().err
    assert main(["fit", str(shards), "--epochs", "1", "--out", str(tmp_path / "no"), "--model", "nbvnet-4-5", "--init", str(plain / "best.pt"), *near]) == 2
    assert "a nbvnet-4-3 checkpoint, and this run trains nbvnet-4-5" in capsys.readouterr().err
