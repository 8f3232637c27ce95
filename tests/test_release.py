"""The released models: installed with the package (not only in the checkout), within 25 MB,
reproducing the answers their card records, used when no checkpoint is given, with a card that
says what they were trained on."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from nbvdata.core.files import shown_path
from nbvtrain.release import (CARD, NETWORKS, REFERENCE, TASKS, ranker_reference_answer, reference_answer,
                              reference_grid, released_checkpoint, released_files, released_ranker)

ROOT = Path(__file__).resolve().parents[1]
FOLDER = ROOT / "nbvtrain" / "released"


def test_the_released_files_are_in_the_package_and_small():
    released = released_files()
    assert sorted(released) == sorted(TASKS), "run nbvtrain release (README: The released models)"
    files = [FOLDER / name for name in released.values()]
    assert all(path.is_file() for path in files), "run nbvtrain release (README: The released models)"
    assert sorted([*FOLDER.glob("*.pt"), FOLDER / "viewrank.json"]) == sorted(files)  # nothing else ships
    assert sum(path.stat().st_size for path in files) <= 25 * 10 ** 6
    from nbvtrain.ranking.viewrank import load_ranker

    ranker = load_ranker(released_ranker())
    assert ranker.kind == "viewrank-gbm" and ranker.scene["grid_size"] == 32
    for task, name in released.items():
        if task not in NETWORKS:
            continue
        state = torch.load(FOLDER / name, weights_only=True)
        assert state["task"] == task and "optimizer" not in state and name == f"{state['model']}.pt"
        assert all(value.dtype == torch.float16 for value in state["state_dict"].values() if value.is_floating_point())
        assert state["scene"]["views_count"] == 500 and state["scene"]["grid_size"] == 32  # the default scene


def test_the_card_names_the_data_and_the_figures():
    card = (FOLDER / CARD).read_text()
    path = ROOT / "manifests" / "train-meshes-1.2.0.json"  # both networks' data (README)
    manifest = json.loads(path.read_text())
    sha = hashlib.sha256(path.read_bytes()).hexdigest()
    assert card.count(f"{manifest['name']} {manifest['version']} (manifest sha256 {sha})") == len(NETWORKS)
    assert "## viewrank: viewrank-gbm" in card and "layouts-tammes-128 1.0.0" in card
    for phrase in ("gain ratio", "min of wall time", "## Evaluation", "| object | scores |", "This card written on:",
                   "## How they were chosen", "validation objects"):
        assert phrase in card


def test_the_released_weights_reproduce_the_recorded_answers():
    recorded = json.loads((FOLDER / REFERENCE).read_text())
    ranker = ranker_reference_answer(released_ranker())
    assert ranker["view"] == recorded["viewrank"]["view"]
    assert ranker["score"] == pytest.approx(recorded["viewrank"]["score"], abs=1e-4)
    for task in NETWORKS:
        answer = reference_answer(released_checkpoint(task))
        np.testing.assert_allclose(answer["direction"], recorded[task]["direction"], atol=1e-4)
        if task == "scores":
            assert answer["view"] == recorded[task]["view"]
            assert answer["score"] == pytest.approx(recorded[task]["score"], abs=1e-3)


def test_an_installed_package_loads_them(tmp_path):
    """pip install (no build isolation, offline) into a folder, then from elsewhere: the released
    model is package data, found without the checkout."""
    target = tmp_path / "site"
    done = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index",
                           "--quiet", "--target", str(target), str(ROOT)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    code = ("import json, sys, nbvtrain.release as r\n"
            "assert r.__file__.startswith(sys.argv[1]), r.__file__\n"
            "answers = {t: r.reference_answer(r.released_checkpoint(t)) for t in r.NETWORKS}\n"
            "print(json.dumps(answers | {'viewrank': r.ranker_reference_answer(r.released_ranker())}))\n")
    done = subprocess.run([sys.executable, "-c", code, str(target)], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path, env={"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr[-2000:]
    answers, recorded = json.loads(done.stdout), json.loads((FOLDER / REFERENCE).read_text())
    assert answers["scores"]["view"] == recorded["scores"]["view"]
    np.testing.assert_allclose(answers["regression"]["direction"], recorded["regression"]["direction"], atol=1e-4)
    assert answers["viewrank"]["view"] == recorded["viewrank"]["view"]


def test_commands_use_the_released_model_without_a_checkpoint(tmp_path, capsys):
    from nbvtrain.cli import main

    np.save(tmp_path / "grid.npy", reference_grid())
    assert main(["predict", str(tmp_path / "grid.npy")]) == 0  # the released ranker, as plan's default
    answer = json.loads(capsys.readouterr().out)
    assert Path(answer["ranker"]).name == released_files()["viewrank"] and answer["scanned"] == []
    assert answer["view"] == json.loads((FOLDER / REFERENCE).read_text())["viewrank"]["view"]


def test_release_names_files_by_network_and_the_card_by_where_it_is_written(tmp_path, capsys):
    """nbvtrain release --out DIR: each checkpoint is named by its own network (not the shipped
    model's name), the card names it relative to itself, reference.json says which file is which
    task's, and a later release replaces a task's model and keeps the other task's."""
    from nbvdata.cli import main as nbvdata
    from nbvtrain.cli import main as nbvtrain

    shards = tmp_path / "shards"
    assert nbvdata(["generate", "--config", str(ROOT / "configs" / "smoke.yaml"), "--runs-per-mesh", "1",
                    "--out", str(shards), "--no-progress"]) == 0
    runs = {model: tmp_path / model for model in ("nbvnet-3-3", "nbvnet-3-5", "nbvscore-3")}
    for model, run in runs.items():
        assert nbvtrain(["fit", str(shards), "--epochs", "1", "--model", model, "--batch-size", "8", "--threads", "1",
                         "--no-progress", "--out", str(run)]) == 0
    out = tmp_path / "release"
    assert nbvtrain(["release", "--regression", str(runs["nbvnet-3-3"]), "--out", str(out)]) == 0
    assert sorted(path.name for path in out.iterdir()) == [CARD, "nbvnet-3-3.pt", REFERENCE]
    assert released_files(out) == {"regression": "nbvnet-3-3.pt"}
    card = (out / CARD).read_text()
    assert "## regression: nbvnet-3-3 (`nbvnet-3-3.pt` beside this card" in card
    assert "nbvtrain/released" not in card and "use by default" not in card  # not the package's models
    recorded = json.loads((out / REFERENCE).read_text())["regression"]
    assert reference_answer(out / "nbvnet-3-3.pt") | {"checkpoint": "nbvnet-3-3.pt"} == recorded

    capsys.readouterr()
    assert nbvtrain(["release", "--regression", str(runs["nbvnet-3-5"]), "--out", str(out)]) == 0
    assert f"removed {out / 'nbvnet-3-3.pt'}" in capsys.readouterr().out
    assert nbvtrain(["release", "--scores", str(runs["nbvscore-3"]), "--out", str(out)]) == 0
    assert released_files(out) == {"regression": "nbvnet-3-5.pt", "scores": "nbvscore-3.pt"}
    assert sorted(path.name for path in out.glob("*.pt")) == ["nbvnet-3-5.pt", "nbvscore-3.pt"]

    # a chosen snapshot of a run (not its best.pt), with notes on how it was chosen; the regression
    # network released before keeps its file and its section of the card, and the notes stay with it
    snapshot = runs["nbvscore-3"] / "snapshots" / "epoch-001.pt"
    snapshot.parent.mkdir()
    snapshot.write_bytes((runs["nbvscore-3"] / "last.pt").read_bytes())
    notes = tmp_path / "notes.md"
    notes.write_text("Chosen on the validation objects in closed loop.\n")
    regression_section = card_section(out / CARD, "regression")
    assert nbvtrain(["release", "--scores", str(snapshot), "--notes", str(notes), "--out", str(out)]) == 0
    card = (out / CARD).read_text()
    assert "released: the epoch `snapshots/epoch-001.pt` of the run, epoch 1." in card
    assert "min of wall time on cpu: " in card_section(out / CARD, "scores")  # the machine it was trained on
    assert "## How they were chosen\n\nChosen on the validation objects in closed loop." in card
    assert card_section(out / CARD, "regression") == regression_section
    assert list(json.loads((out / REFERENCE).read_text())) == list(NETWORKS)  # the card's order, scores released last
    assert torch.load(out / "nbvscore-3.pt", weights_only=True)["released_from"] == shown_path(snapshot)
    assert nbvtrain(["release", "--regression", str(runs["nbvnet-3-3"]), "--out", str(out)]) == 0
    card = (out / CARD).read_text()
    assert "Chosen on the validation objects in closed loop." in card and "## scores: nbvscore-3" in card
    assert card.index("## scores:") < card.index("## regression:") < card.index("## How they were chosen")
    assert "released: the best epoch (lowest validation loss), epoch 1." in card_section(out / CARD, "regression")
    assert nbvtrain(["release", "--scores", str(tmp_path / "notes.md"), "--out", str(out)]) == 2
    assert "neither a run folder of nbvtrain fit nor a checkpoint file inside one" in capsys.readouterr().err
    # bad run folders: one line, and no --out folder made (before issue 50 an empty one was left)
    empty_run = tmp_path / "empty-run"
    empty_run.mkdir()
    for argv in (["--scores", str(tmp_path / "notes.md")], ["--scores", str(empty_run)],
                 ["--scores", str(runs["nbvscore-3"]), "--regression", str(runs["nbvscore-3"])]):
        assert nbvtrain(["release", *argv, "--out", str(tmp_path / "never")]) == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1 and not (tmp_path / "never").exists()


def card_section(card: Path, task: str) -> str:
    text = card.read_text()
    start = text.index(f"## {task}: ")
    return text[start:text.index("\n## ", start)]
