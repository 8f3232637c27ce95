"""What both command lines share (nbvdata.commandline): every number option checked by argparse in
one line with exit status 2, and a quiet exit when the reader of stdout goes away (``| head -1``)."""

import argparse
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from nbvdata.cli import build_parser as nbvdata_parser
from nbvdata.cli import main as nbvdata_main
from nbvdata.commandline import Integer, Number
from nbvdata.core.config import SimConfig
from nbvdata.core.views import view_sphere
from nbvdata.simulation.sensor import MeshScanner
from nbvdata.simulation.shapes import builtin_object
from nbvtrain.cli import build_parser as nbvtrain_parser
from nbvtrain.networks.config import TrainConfig
from nbvtrain.networks.models import build_model
from nbvtrain.networks.train import save_training_state

ROOT = Path(__file__).resolve().parents[1]
PARSERS = {"nbvdata": nbvdata_parser, "nbvtrain": nbvtrain_parser}


def _number_options():
    """(program, command, option string, argparse type) of every option of every command whose
    value is a number: every one must use a checked type of nbvdata.commandline."""
    found = []
    for program, build in PARSERS.items():
        sub = next(a for a in build()._actions if isinstance(a, argparse._SubParsersAction))
        for command, parser in sub.choices.items():
            for action in parser._actions:
                if action.type in (int, float) or isinstance(action.type, (Integer, Number)):
                    found.append((program, command, action.option_strings[-1], action.type))
    return found


NUMBER_OPTIONS = _number_options()


def _refused(kind) -> list[str]:
    """Values an option of type ``kind`` must refuse."""
    if kind in (int, float):  # an unchecked type: the test below fails on it
        return []
    if isinstance(kind, Integer):
        return sorted({str(kind.minimum - 1), "-1", "abc", "1.5", ""} - {str(v) for v in range(kind.minimum, 3)})
    bad = ["nan", "inf", "-inf", "abc", ""]
    bad += [repr(kind.low)] if kind.low_open else [repr(kind.low - 0.5)]
    bad += [repr(kind.high + 0.5)] if math.isfinite(kind.high) else []
    return bad


def _accepted(kind) -> str:
    if isinstance(kind, Integer):
        return str(kind.minimum)
    return repr(kind.low + 0.25 if kind.low_open or math.isfinite(kind.high) else kind.low)


def test_the_walk_finds_the_options_it_should():
    names = {(program, command, option) for program, command, option, _ in NUMBER_OPTIONS}
    assert {("nbvdata", "demo", "--scans"), ("nbvdata", "import-legacy", "--limit"), ("nbvtrain", "predict", "--k"),
            ("nbvtrain", "predict", "--radius"), ("nbvtrain", "fit", "--epochs"), ("nbvtrain", "plan", "--size"),
            ("nbvtrain", "evaluate", "--scans"), ("nbvtrain", "baselines", "--memory-limit-gb")} <= names
    assert len(names) > 30


@pytest.mark.parametrize("program, command, option, kind", NUMBER_OPTIONS,
                         ids=[f"{p} {c} {o}" for p, c, o, _ in NUMBER_OPTIONS])
def test_every_number_option_refuses_bad_values_in_one_line(program, command, option, kind, capsys):
    assert kind not in (int, float), f"{program} {command} {option}: use a checked type of nbvdata.commandline"
    parser = PARSERS[program]()
    for value in _refused(kind):
        with pytest.raises(SystemExit) as done:
            parser.parse_args([command, f"{option}={value}"])
        assert done.value.code == 2, (option, value)
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err, err
        assert err.startswith(f"{program} {command}: error: argument {option}") and f"{program} {command} --help" in err
    value = _accepted(kind)  # the smallest good value passes (the command may then miss other arguments)
    try:
        parser.parse_args([command, f"{option}={value}"])
    except SystemExit:
        pass
    assert f"argument {option}" not in capsys.readouterr().err


def test_the_checked_types():
    from nbvdata.commandline import fraction, non_negative_int, positive_float, positive_int

    assert positive_int("3") == 3 and non_negative_int("0") == 0 and positive_float("2.5") == 2.5
    assert fraction("0") == 0 and fraction("1") == 1
    for kind, value in ((positive_int, "0"), (non_negative_int, "-1"), (positive_float, "0"), (positive_float, "nan"),
                        (positive_float, "1e999"), (fraction, "1.01"), (positive_int, "2.0")):
        with pytest.raises(argparse.ArgumentTypeError):
            kind(value)


@pytest.mark.parametrize("scans", ["0", "-2", "abc"])
def test_demo_without_scans_is_one_line_and_exit_2(scans, tmp_path, capsys):
    with pytest.raises(SystemExit) as done:
        nbvdata_main(["demo", "--scans", scans, "--out", str(tmp_path / "d.png")])
    assert done.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("nbvdata demo: error: argument --scans: ") and len(err.splitlines()) == 1, err
    assert not (tmp_path / "d.png").exists()


def test_a_usage_error_is_one_line_naming_help(capsys):
    with pytest.raises(SystemExit) as done:
        nbvdata_main(["inspect"])
    assert done.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "required: shards" in err and "nbvdata inspect --help" in err, err


# ---- a closed pipe: `nbvtrain plan ... | head -1` ----------------------------------------------------------


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """One small shard, a checkpoint, a grid and a robot's scan: the inputs of the commands below."""
    folder = tmp_path_factory.mktemp("pipe")
    import trimesh

    trimesh.creation.box(extents=(0.1, 0.08, 0.06)).export(folder / "box.stl")
    assert nbvdata_main(["generate", "--config", str(ROOT / "configs" / "smoke.yaml"), "--meshes",
                         str(folder / "box.stl"), "--runs-per-mesh", "2", "--out", str(folder / "shards"),
                         "--no-progress"]) == 0
    torch.manual_seed(0)
    net = build_model("nbvnet-3-3")
    save_training_state(folder / "best.pt", net, torch.optim.Adam(net.parameters()), TrainConfig(model="nbvnet-3-3"), [], 0, 0.4)
    np.save(folder / "grid.npy", np.full((32, 32, 32), 0.5, dtype=np.float32))
    config = SimConfig()
    pose = view_sphere(config.views)[7]
    scan = MeshScanner(builtin_object("mug", config.mesh).mesh, config.sensor, threads=1).scan(pose)
    np.save(folder / "cloud.npy", scan.points.astype(np.float64))
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = pose.rotation.T, scan.origin
    (folder / "scans.yaml").write_text(yaml.safe_dump([{"cloud": "cloud.npy", "pose": matrix.tolist()}]))
    return {"folder": folder, "shards": folder / "shards", "checkpoint": folder / "best.pt",
            "grid": folder / "grid.npy", "scans": folder / "scans.yaml"}


def _into_a_closed_pipe(argv: list[str], cwd: Path, buffered: bool) -> subprocess.CompletedProcess:
    """Run ``argv`` with stdout a pipe whose reader has already gone, as after `| head -1` has read
    its line; ``buffered``: stdout block-buffered as usual, else as under PYTHONUNBUFFERED=1."""
    read, write = os.pipe()
    os.close(read)
    env = {key: value for key, value in os.environ.items() if key != "PYTHONUNBUFFERED"}
    env.update(PYTHONPATH=str(ROOT), **({} if buffered else {"PYTHONUNBUFFERED": "1"}))
    try:
        return subprocess.run(argv, stdout=write, stderr=subprocess.PIPE, text=True, cwd=cwd, timeout=300, env=env)
    finally:
        os.close(write)


COMMANDS = {
    "nbvdata inspect": lambda i: ["-m", "nbvdata", "inspect", str(i["shards"]), "--by-step"],
    "nbvdata show": lambda i: ["-m", "nbvdata", "show", str(i["grid"]), "--out", str(i["folder"] / "g.png")],
    "nbvdata --help": lambda i: ["-m", "nbvdata", "--help"],
    "nbvtrain predict": lambda i: ["-m", "nbvtrain", "predict", str(i["grid"]), "--checkpoint", str(i["checkpoint"])],
    "nbvtrain plan": lambda i: ["-m", "nbvtrain", "plan", "--scans", str(i["scans"]), "--center", "0,0,0",
                                "--checkpoint", str(i["checkpoint"])],
    "nbvtrain baselines": lambda i: ["-m", "nbvtrain", "baselines", str(i["shards"])],
    "nbvtrain --version": lambda i: ["-m", "nbvtrain", "--version"],
}
CASES = [(command, True) for command in COMMANDS] + [(command, False) for command in
                                                     ("nbvdata inspect", "nbvtrain plan", "nbvdata --help")]


@pytest.mark.parametrize("command, buffered", CASES, ids=[f"{c}, {'buffered' if b else 'unbuffered'}" for c, b in CASES])
def test_a_closed_pipe_ends_the_command_quietly(command, buffered, inputs):
    done = _into_a_closed_pipe([sys.executable, *COMMANDS[command](inputs)], inputs["folder"], buffered)
    # argparse drops a failed write of --help or --version itself; unbuffered, nothing is left to fail after it
    status = 0 if command.endswith(("--help", "--version")) and not buffered else 141
    assert done.stderr == "" and done.returncode == status, (done.returncode, done.stderr[-2000:])


def test_a_closed_pipe_through_the_console_script_and_a_shell(inputs):
    """`nbvdata inspect SHARDS | true` in a shell, as a user types it: nothing on stderr, and (with
    pipefail) the status of a tool stopped by SIGPIPE."""
    script = Path(sys.executable).parent / "nbvdata"
    if not script.exists():
        pytest.skip(f"{script} is absent: the package is not installed in this environment (pip install -e .)")
    done = subprocess.run(["bash", "-o", "pipefail", "-c", f"'{script}' inspect '{inputs['shards']}' | true"],
                          capture_output=True, text=True, timeout=300)  # true has gone long before Python writes
    assert done.stderr == "" and done.returncode == 141, (done.returncode, done.stderr[-2000:])


def test_a_broken_pipe_that_is_not_stdout_is_not_hidden(tmp_path):
    """A BrokenPipeError from another pipe (a worker's, say) while stdout is fine stays an error."""
    script = ("from nbvdata.commandline import exit_quietly_when_stdout_closes\n"
              "@exit_quietly_when_stdout_closes\n"
              "def main(argv=None):\n"
              "    print('working')\n"
              "    raise BrokenPipeError(32, 'a worker went away')\n"
              "main()\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert done.returncode == 1 and "BrokenPipeError: [Errno 32] a worker went away" in done.stderr
    assert done.stdout == "working\n"
