"""Rerun recordings (``nbvdata.view.rerun``): what each command writes loads back with Rerun's own
reader and holds every entity at every scan; recording changes no shard and no evaluation row; a
missing viz extra is one line and exit 2."""

from __future__ import annotations

import csv
import hashlib
import os
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rerun", reason="rerun-sdk (the viz extra) is not installed")
from rerun.chunk import RrdReader  # noqa: E402

from nbvdata.cli import main  # noqa: E402
from nbvdata.schema.shards import Shard  # noqa: E402
from nbvdata.simulation.shapes import BUILTIN_SHAPES  # noqa: E402
from nbvdata.view.rerun import NO_GAIN, gain_colours  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs" / "smoke.yaml"
SMALL = ["--set", "views.count=50", "--set", "coverage.points=2000", "--set", "sensor.width=44",
         "--set", "sensor.height=36"]
PER_STEP = ("grid/occupied", "grid/unknown", "views/candidates", "views/sensor", "views/path", "views/chosen",
            "views/nbv", "coverage")


def read_recording(path: Path) -> dict[str, dict]:
    """{entity path: {"static": {component: value}, scan: {component: value}}}, read with Rerun's
    ``RrdReader``: every row of every chunk of the file's recording (chunks come in no fixed order)."""
    entities: dict[str, dict] = defaultdict(dict)
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        columns = {name: batch.column(name).to_pylist() for name in batch.column_names
                   if ":" in name and name != "rerun.controls.RowId"}
        scans = batch.column("scan").to_pylist() if "scan" in batch.column_names else [None] * batch.num_rows
        for row, scan in enumerate(scans):
            entry = entities[chunk.entity_path].setdefault("static" if scan is None else scan, {})
            entry.update({name: values[row] for name, values in columns.items() if values[row] is not None})
    return dict(entities)


def runs_of(entities: dict[str, dict]) -> dict[str, int]:
    """{run root: its number of steps}, runs being the roots that hold a mesh."""
    roots = [path.removesuffix("/mesh") for path in entities if path.endswith("/mesh")]
    return {root: len([key for key in entities[f"{root}/coverage"] if key != "static"]) for root in roots}


def check_run(entities: dict[str, dict], root: str, steps: int) -> None:
    """Every entity of a run at every step: the mesh once, scan k's points at step k only, the
    per-step entities at steps 1..steps, the chosen arrow cleared at the last."""
    assert "Mesh3D:triangle_indices" in entities[f"{root}/mesh"]["static"]
    for name in PER_STEP:
        assert sorted(key for key in entities[f"{root}/{name}"] if key != "static") == list(range(1, steps + 1)), name
    for step in range(1, steps + 1):
        assert list(entities[f"{root}/scans/{step:02d}"]) == [step]
        assert len(entities[f"{root}/scans/{step:02d}"][step]["Points3D:positions"]) > 0
        assert len(entities[f"{root}/views/path"][step]["LineStrips3D:strips"][0]) == step
    scans = {path for path in entities if path.startswith(f"{root}/scans/")}
    assert len(scans) == steps
    chosen = entities[f"{root}/views/chosen"]
    assert all("Arrows3D:origins" in chosen[step] for step in range(1, steps))
    assert "Clear:is_recursive" in chosen[steps] and "Arrows3D:origins" not in chosen[steps]


def test_gain_colours_ramp_over_the_valid_views():
    colours = gain_colours(np.array([0.0, 0.1, 0.4, 0.2, 0.9]), np.array([True, True, True, True, False]))
    assert colours.dtype == np.uint8 and colours.shape == (5, 4)
    assert tuple(colours[0]) == tuple(colours[4]) == NO_GAIN  # no gain; not valid (however large its gain)
    assert tuple(colours[2, :3]) == (253, 231, 37)  # the best valid view: the ramp's top
    assert colours[1, 1] < colours[3, 1] < colours[2, 1]  # dark to bright with the gain (green rises)


def test_demo_records_every_scan(tmp_path, capsys):
    out = tmp_path / "demo.rrd"
    assert main(["demo", "--scans", "3", *SMALL, "--out", str(tmp_path / "demo.png"), "--rerun", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed
    entities = read_recording(out)
    assert runs_of(entities) == {"/demo": 3}
    check_run(entities, "/demo", 3)
    # the boxes are the grid's occupied voxels, as the demo counts them, at every scan
    occupied = [int(line.split("'occupied': ")[1].split(",")[0]) for line in printed.splitlines()
                if line.startswith("scan ")]
    assert [len(entities["/demo/grid/occupied"][step]["Boxes3D:centers"]) for step in (1, 2, 3)] == occupied
    coverage = [entities["/demo/coverage"][step]["Scalars:scalars"][0] for step in (1, 2, 3)]
    assert coverage == sorted(coverage) and 0 < coverage[0] <= 100
    assert not [path for path in tmp_path.iterdir() if path.name.startswith(".")]  # the partial was renamed


def _digests(folder: Path) -> dict[str, str]:
    return {path.name: hashlib.sha256(path.read_bytes()).hexdigest()
            for path in sorted([*folder.glob("*.h5"), folder / "config.yaml"])}


def test_generate_records_the_first_runs_and_writes_the_same_shards(tmp_path, capsys):
    plain, recorded = tmp_path / "plain", tmp_path / "recorded"
    common = ["generate", "--config", str(SMOKE), "--set", "generate.runs_per_shard=2"]
    sources = ["--meshes", str(tmp_path / "meshes")]
    (tmp_path / "meshes").mkdir()
    for name in ("mug", "ring"):
        BUILTIN_SHAPES[name]().export(tmp_path / "meshes" / f"{name}.obj")
    assert main([*common, *sources, "--out", str(plain), "--workers", "1"]) == 0
    assert main([*common, *sources, "--out", str(recorded), "--workers", "2", "--rerun-runs", "1"]) == 0
    assert "2 Rerun recordings in" in capsys.readouterr().out
    assert _digests(recorded) == _digests(plain) and len(_digests(plain)) == 5  # 4 shards and config.yaml
    # one recording per shard holding a run < 1: runs 0-1 of each mesh, not runs 2-3
    files = sorted(path.name for path in (recorded / "rerun").iterdir())
    assert files == sorted(path.with_suffix(".rrd").name for path in recorded.glob("*-runs0000-0002.h5"))
    for name in files:
        entities = read_recording(recorded / "rerun" / name)
        with Shard(recorded / name.replace(".rrd", ".h5")) as shard:
            first = shard["run"] == 0
            nbv, positions = shard["nbv_index"][first], shard["view_positions"]
            coverage = shard["coverage"][first][:, 0]
        assert runs_of(entities) == {"/run_0000": len(nbv)}
        check_run(entities, "/run_0000", len(nbv))
        arrows = entities["/run_0000/views/nbv"]
        for step, view in enumerate(nbv, start=1):  # the NBV arrow starts at the shard's NBV
            assert np.allclose(arrows[step]["Arrows3D:origins"][0], positions[view], atol=1e-6)
            assert np.isclose(entities["/run_0000/coverage"][step]["Scalars:scalars"][0], 100 * coverage[step - 1])


def test_a_killed_writers_half_recordings_are_swept(tmp_path, capsys):
    """A recording worker killed mid-file leaves ``.NAME.rrd.HOST-PID.tmp``: the next job deletes
    those of dead processes on this machine (and a unit's own when it claims the unit), never a
    live process's or another machine's."""
    from nbvdata.core.files import host_tag

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(gone.stdout)
    out = tmp_path / "out"
    (out / "rerun").mkdir(parents=True)
    dead = out / "rerun" / f".x.rrd.{host_tag()}-{dead_pid}.tmp"
    live = out / "rerun" / f".y.rrd.{host_tag()}-{os.getpid()}.tmp"
    other = out / "rerun" / f".z.rrd.another-host-{dead_pid}.tmp"
    for path in (dead, live, other):
        path.write_bytes(b"half a recording")
    assert main(["generate", "--config", str(SMOKE), "--out", str(out), "--runs-per-mesh", "1", "--rerun-runs", "1",
                 "--set", "episode.max_scans=2", "--no-progress"]) == 0
    assert not dead.exists() and live.exists() and other.exists()
    assert not [path for path in (out / "rerun").iterdir() if path.suffix == ".tmp" and path not in (live, other)]


def test_evaluate_records_every_planner_side_by_side(tmp_path, capsys):
    pytest.importorskip("torch", reason="nbvtrain needs torch")
    from nbvtrain.cli import main as nbvtrain_main

    meshes = tmp_path / "meshes"
    meshes.mkdir()
    for name in ("mug", "ring"):
        BUILTIN_SHAPES[name]().export(meshes / f"{name}.obj")
    argv = ["evaluate", "--meshes", str(meshes), "--planners", "oracle,random", "--scans", "3", "--random-starts", "1",
            "--no-floors", "--config", str(SMOKE), "--no-progress"]
    assert nbvtrain_main([*argv, "--out", str(tmp_path / "plain")]) == 0
    assert nbvtrain_main([*argv, "--out", str(tmp_path / "recorded"), "--rerun", str(tmp_path / "rrd")]) == 0
    rows = {}
    for run in ("plain", "recorded"):
        with open(tmp_path / run / "coverage.csv") as handle:
            rows[run] = [{key: value for key, value in row.items() if key != "seconds"} for row in csv.DictReader(handle)]
    assert rows["recorded"] == rows["plain"]  # recording changes no row
    assert sorted(path.name for path in (tmp_path / "rrd").iterdir()) == ["mug.rrd", "ring.rrd"]
    for mesh in ("mug", "ring"):
        entities = read_recording(tmp_path / "rrd" / f"{mesh}.rrd")
        roots = [f"/{planner}/start_{start}" for planner in ("oracle", "random") for start in (0, 1)]
        assert runs_of(entities) == dict.fromkeys(roots, 3)
        for root in roots:
            check_run(entities, root, 3)
            planner, start = root.strip("/").split("/start_")
            expected = [100 * float(row["observable_coverage"]) for row in rows["plain"]
                        if (row["mesh"], row["planner"], row["start"]) == (mesh, planner, start)]
            assert np.allclose([entities[f"{root}/coverage"][step]["Scalars:scalars"][0] for step in (1, 2, 3)],
                               expected, atol=1e-4)


NO_RERUN = "import sys; sys.modules['rerun'] = None  # any `import rerun` now raises ImportError\n"


@pytest.mark.parametrize("command", [
    "from nbvdata.cli import main; sys.exit(main(['demo', '--rerun', 'x.rrd']))",
    "from nbvdata.cli import main; sys.exit(main(['generate', '--out', 'out', '--rerun-runs', '1']))",
    "from nbvtrain.cli import main; sys.exit(main(['evaluate', '--meshes', 'm', '--rerun', 'rrd']))",
], ids=["demo", "generate", "evaluate"])
def test_a_missing_viz_extra_is_one_line_and_exit_2(tmp_path, command):
    if "nbvtrain" in command:
        pytest.importorskip("torch", reason="nbvtrain needs torch")
    done = subprocess.run([sys.executable, "-c", NO_RERUN + command], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    err = done.stderr.strip()
    assert done.returncode == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert "needs rerun-sdk, which is not installed" in err and 'pip install -e ".[viz]"' in err
    assert not list(tmp_path.iterdir())  # refused before anything was written
