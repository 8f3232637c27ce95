"""The generator job: same arrays whatever the workers or backend, resume after a kill,
bad meshes reported while the others go on."""

import hashlib
import json
import os
import re
import selectors
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh
from conftest import PUBLISHING, about

from nbvdata.cli import main
from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.claims import claim, folder_lock, partial_path
from nbvdata.datasets.generate import FAILURES_FILE, generate, plan_units
from nbvdata.schema.shards import Shard, ShardError
from nbvdata.simulation.shapes import builtin_object
from nbvdata.simulation.sources import builtin_sources, mesh_sources, part_sources

SMOKE = Path(__file__).resolve().parents[1] / "configs" / "smoke.yaml"
DATA = [name for name in ("grids", "grid_palette", "nbv_index", "nbv_pose", "nbv_position", "gains",
                          "overlaps", "coverage", "mesh_id", "run", "step", "last_view", "seed",
                          "view_positions", "view_poses")]


def _config(*overrides: str) -> SimConfig:
    return load_config(SimConfig, SMOKE, list(overrides))


def _read(out_dir: Path) -> dict[str, dict[str, np.ndarray]]:
    """Every shard of a folder: {file name: {dataset: array}}."""
    shards = {}
    for path in sorted(out_dir.glob("*.h5")):
        with Shard(path) as shard:
            shards[path.name] = {name: shard[name] for name in DATA}
    return shards


def _per_mesh(shards: dict[str, dict[str, np.ndarray]]) -> dict[bytes, dict[str, np.ndarray]]:
    """The samples of each mesh in run order, decoded, whatever the split into shards."""
    merged: dict[bytes, dict[str, list]] = {}
    for arrays in shards.values():
        if not len(arrays["nbv_index"]):
            continue
        mesh = merged.setdefault(arrays["mesh_id"][0], {})
        mesh.setdefault("grids", []).append(arrays["grid_palette"][arrays["grids"]])
        for name in ("nbv_index", "gains", "overlaps", "coverage", "run", "step", "seed"):
            mesh.setdefault(name, []).append(arrays[name])
    result = {}
    for mesh_id, columns in merged.items():
        order = np.argsort(np.concatenate(columns["run"]), kind="stable")
        result[mesh_id] = {name: np.concatenate(parts)[order] for name, parts in columns.items()}
    return result


def _assert_same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        for name in a[key]:
            assert np.array_equal(a[key][name], b[key][name]), (key, name)


@pytest.fixture(scope="module")
def sources():
    return builtin_sources()[:3]


@pytest.fixture(scope="module")
def reference(tmp_path_factory, sources):
    """One worker, two runs per shard: the arrays every other way of running must give."""
    out = tmp_path_factory.mktemp("reference")
    report = generate(sources, out, _config("generate.workers=1", "generate.runs_per_shard=2"))
    assert not report.failures and report.samples > 0
    assert len(report.done) == len(plan_units(sources, _config("generate.runs_per_shard=2"))) == 6
    return _read(out)


@pytest.mark.parametrize("backend", ["loky", "threading"])
def test_two_workers_give_the_same_shards_as_one(tmp_path, sources, reference, backend):
    generate(sources, tmp_path, _config("generate.workers=2", "generate.runs_per_shard=2",
                                        f"generate.backend={backend}"))
    _assert_same(_read(tmp_path), reference)


def test_a_local_dask_cluster_gives_the_same_shards(tmp_path, sources, reference):
    pytest.importorskip("dask.distributed", reason="the dask extra is not installed: pip install -e '.[dask]'")
    report = generate(sources, tmp_path, _config("generate.workers=2", "generate.runs_per_shard=2",
                                                 "generate.backend=dask"))
    assert not report.failures
    _assert_same(_read(tmp_path), reference)


def test_a_scheduler_that_does_not_answer_is_one_line(tmp_path, capsys, monkeypatch):
    pytest.importorskip("dask.distributed", reason="the dask extra is not installed: pip install -e '.[dask]'")
    import nbvdata.datasets.generate as job
    from nbvdata.cli import main

    monkeypatch.setattr(job, "SCHEDULER_WAIT", 1)
    assert main(["generate", "--out", str(tmp_path / "out"), "--backend", "dask", "--scheduler", "tcp://127.0.0.1:1",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no Dask scheduler answered within 1 s" in err


def test_the_split_into_shards_does_not_change_the_samples(tmp_path, sources, reference):
    generate(sources, tmp_path, _config("generate.workers=1"))  # one shard per mesh
    assert len(list(tmp_path.glob("*.h5"))) == 3
    _assert_same(_per_mesh(_read(tmp_path)), _per_mesh(reference))


def test_units_of_one_mesh_share_one_scene_and_the_same_bytes(tmp_path, sources, monkeypatch):
    """runs_per_shard=1: the scene is cast once per mesh in a process, and the shards are the
    bytes of a job that casts it for every unit."""
    import nbvdata.datasets.generate as job

    config = _config("generate.workers=1", "generate.runs_per_shard=1", "episode.runs_per_mesh=3")
    build, built = job.Scene.build, []
    monkeypatch.setattr(job.Scene, "build", lambda obj, *rest: built.append(obj.mesh_id) or build(obj, *rest))
    monkeypatch.setattr(job, "_SCENES", threading.local())
    generate(sources[:2], tmp_path / "reused", config)
    assert sorted(built) == sorted(source.mesh_id for source in sources[:2])
    built.clear()
    monkeypatch.setattr(job, "SCENE_CACHE_SIZE", 0)
    monkeypatch.setattr(job, "_SCENES", threading.local())
    generate(sources[:2], tmp_path / "rebuilt", config)
    assert len(built) == 6
    digests = {name: [hashlib.sha256((tmp_path / folder / name).read_bytes()).hexdigest()
                      for folder in ("reused", "rebuilt")] for name in _read(tmp_path / "reused")}
    assert len(digests) == 6 and all(a == b for a, b in digests.values())


def test_another_seed_gives_other_runs(tmp_path, sources, reference):
    generate(sources, tmp_path, _config("generate.workers=1", "generate.runs_per_shard=2", "episode.seed=1"))
    other = _read(tmp_path)
    assert other.keys() == reference.keys()
    assert any(not np.array_equal(other[k]["nbv_index"], reference[k]["nbv_index"]) for k in other)


def _command(out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "nbvdata", "generate", "--out", str(out), "--config", str(SMOKE),
            "--workers", "1", "--set", "generate.runs_per_shard=1", "--runs-per-mesh", "6", *extra]


def test_a_killed_run_resumes_without_losing_or_repeating_a_unit(tmp_path):
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    subprocess.run(_command(whole, "--no-progress"), check=True, capture_output=True)
    total = sorted(p.name for p in whole.glob("*.h5"))
    assert len(total) == 36  # 6 shapes x 6 runs, one run per shard

    process = subprocess.Popen(_command(killed, "--no-progress"), stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 120
    while not list(killed.glob("*.h5")) and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.005)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    written = sorted(p.name for p in killed.glob("*.h5"))
    assert 0 < len(written) < len(total), "the kill should land mid-job"
    for name in written:  # what the killed job left is whole
        Shard(killed / name).close()
    before = {name: (killed / name).stat().st_mtime_ns for name in written}

    result = subprocess.run(_command(killed, "--no-progress"), capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert f"; {len(written)} shard" in result.stdout and "already there" in result.stdout
    assert sorted(p.name for p in killed.glob("*.h5")) == total
    assert not list(killed.glob("*.partial"))
    assert all((killed / name).stat().st_mtime_ns == mtime for name, mtime in before.items())  # not rewritten
    _assert_same(_read(killed), _read(whole))


def test_resume_redoes_a_broken_shard_and_drops_partial_files(tmp_path, sources):
    config = _config("generate.workers=1")
    generate(sources, tmp_path, config)
    first = sorted(tmp_path.glob("*.h5"))[0]
    good = first.read_bytes()
    first.write_bytes(good[:1000])
    (tmp_path / "x.h5.partial").write_bytes(b"half")
    report = generate(sources, tmp_path, config)
    assert [r.unit.shard_name for r in report.done] == [first.name] and len(report.skipped) == 2
    assert first.read_bytes() == good and not (tmp_path / "x.h5.partial").exists()


def _write_meshes(folder: Path) -> None:
    folder.mkdir()
    mug = builtin_object("mug", SimConfig().mesh).mesh
    trimesh.Trimesh(mug.vertices, mug.faces).export(folder / "mug.obj")
    (folder / "broken.obj").write_text("v 0 0 0\nthis is not an obj file\nf 1 2 9\n")
    (folder / "empty.stl").write_bytes(b"")


def test_bad_meshes_are_reported_and_the_others_go_on(tmp_path, capsys):
    meshes, out = tmp_path / "meshes", tmp_path / "out"
    _write_meshes(meshes)
    argv = ["generate", "--meshes", str(meshes), "--out", str(out), "--config", str(SMOKE), "--workers", "1"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "broken.obj" in err and "empty.stl" in err and FAILURES_FILE in err
    failures = (out / FAILURES_FILE).read_text().splitlines()
    assert failures[0] == "mesh\treason" and len(failures) == 3
    assert {Path(line.split("\t")[0]).name for line in failures[1:]} == {"broken.obj", "empty.stl"}
    assert all(line.split("\t")[1] for line in failures[1:])  # each with its reason
    for line in failures[1:]:  # the path said once, in its column; stderr names the file once
        path, reason = line.split("\t")
        assert path not in reason and err.count(path) == 0 and err.count(Path(path).name) == 1, line
    shards = list(out.glob("mug-*.h5"))
    assert len(shards) == 1 and len(Shard(shards[0])) > 0

    assert main(argv) == 1  # still failing, and the good shard is kept, not redone
    assert "; 1 shard was already there" in capsys.readouterr().out


@pytest.mark.parametrize("setup, argv, message", [
    ("empty", ["--meshes", "{meshes}"], "no mesh files"),
    ("missing", ["--meshes", "{tmp}/nowhere"], "nowhere: no such file or folder; pass a folder of mesh files, one "
                "mesh file (.obj, .ply, .off, .stl, .glb, .gltf) or a .txt list"),
    ("done", ["--seed", "5"], "episode.seed"),
    ("none", ["--set", "episode.max_scan=3"], "did you mean 'episode.max_scans'"),
])
def test_generate_user_errors_are_one_line_and_exit_2(tmp_path, capsys, setup, argv, message):
    meshes, out = tmp_path / "meshes", tmp_path / "out"
    meshes.mkdir()
    if setup == "done":
        assert main(["generate", "--out", str(out), "--config", str(SMOKE), "--runs-per-mesh", "1",
                     "--no-progress"]) == 0
        capsys.readouterr()
    argv = [a.format(meshes=meshes, tmp=tmp_path) for a in argv]
    assert main(["generate", "--out", str(out), "--config", str(SMOKE), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_inspect_and_show_read_generated_shards(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["generate", "--out", str(out), "--config", str(SMOKE), "--workers", "1", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["inspect", str(out)]) == 0
    printed = capsys.readouterr().out
    for shape in ("mug", "ring", "pill"):
        assert shape in printed
    shard = sorted(out.glob("*.h5"))[0]
    png = tmp_path / "sample.png"
    assert main(["show", str(shard), "--index", "1", "--out", str(png)]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert main(["show", str(shard), "--index", "999", "--out", str(png)]) == 2
    assert "holds" in capsys.readouterr().err

    shard.write_bytes(shard.read_bytes()[:500])
    assert main(["inspect", str(out)]) == 2
    printed = capsys.readouterr()
    assert shard.name in printed.err and not printed.out  # no table of the other shards first


def test_meshes_of_one_file_name_keep_their_path_in_shards_inspect_and_publish(tmp_path, capsys):
    """ShapeNet's CAT/ID/models/model_normalized.obj: the path under --meshes is the source shards,
    inspect, the manifest and the card record, and names the shards; a version's part finds them
    again by it."""
    meshes = tmp_path / "meshes"
    models = ("02/aa/models", "02/bb/models", "03/cc/models")
    for extents, model in zip(((1, 2, 3), (3, 1, 1), (1, 1, 2)), models):
        (meshes / model).mkdir(parents=True)
        trimesh.creation.box(extents=extents).export(meshes / model / "model_normalized.obj")
    out = tmp_path / "out"
    assert main(["generate", "--meshes", str(meshes), "--out", str(out), "--config", str(SMOKE), "--set",
                 "episode.runs_per_mesh=1", "--workers", "1", "--no-progress"]) == 0
    sources = {f"{model}/model_normalized.obj" for model in models}
    shards = sorted(out.glob("*.h5"))
    assert sorted(path.name.rsplit("-", 3)[0] for path in shards) == sorted(
        f"{model.replace('/', '-')}-model_normalized" for model in models)
    recorded = set()
    for path in shards:
        with Shard(path) as shard:
            recorded |= {mesh["source"] for mesh in shard.info.meshes}
    assert recorded == sources
    capsys.readouterr()
    assert main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    assert all(source in text for source in sources)
    assert main(["publish", *PUBLISHING, str(out), "--name", "shapenet-like", "--version", "1.0.0", "--manifests",
                 str(tmp_path / "manifests"), "--meshes", str(meshes), "--val-fraction", "0.34",
                 "--test-fraction", "0"]) == 0
    warned = capsys.readouterr().err
    assert "no license recorded for 3 meshes" in warned and all(source in warned for source in sources)
    manifest = tmp_path / "manifests" / "shapenet-like-1.0.0.json"
    assert {mesh["source"] for mesh in json.loads(manifest.read_text())["meshes"]} == sources
    assert all(source in (tmp_path / "manifests" / "shapenet-like-1.0.0.md").read_text() for source in sources)
    found, _ = part_sources(manifest, "train", tmp_path)  # a root above --meshes: found by the path's end
    assert {source.title for source in found} <= {f"meshes/{source}" for source in sources} and found


def test_mesh_lists_resolve_relative_to_the_list(tmp_path):
    meshes = tmp_path / "meshes"
    _write_meshes(meshes)
    listing = tmp_path / "list.txt"
    listing.write_text("# two files\nmeshes/mug.obj\n\nmeshes/broken.obj  # bad\n")
    sources, failures = mesh_sources(listing)
    assert [s.name for s in sources] == ["mug.obj", "broken.obj"] and not failures


# ---------------------------------------------------------------------------------------------
# Several processes on one folder (nbvdata.datasets.claims)

COMMAND_SETTINGS = ["generate.runs_per_shard=1", "episode.runs_per_mesh=6"]  # those of _command


def _hashes(folder: Path) -> dict[str, str]:
    """sha256 of each shard of a folder, by name."""
    return {path.name: hashlib.sha256(path.read_bytes()).hexdigest() for path in sorted(folder.glob("*.h5"))}


@pytest.fixture(scope="module")
def single_run(tmp_path_factory) -> dict[str, str]:
    """sha256 of each shard of ``_command`` run by one process: what any split of the work must give."""
    out = tmp_path_factory.mktemp("single") / "out"
    subprocess.run(_command(out, "--no-progress"), check=True, capture_output=True, timeout=120)
    return _hashes(out)


def _start(command: list[str]) -> subprocess.Popen:
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0,
                            env=os.environ | {"PYTHONUNBUFFERED": "1"}, start_new_session=True)


def _read_until(process: subprocess.Popen, text: bytes, timeout: float = 60) -> bytes:
    """The process's stdout up to and including ``text``, read unbuffered (``communicate`` gets the
    rest); fails after ``timeout`` seconds or at its end."""
    out, deadline = b"", time.monotonic() + timeout
    with selectors.DefaultSelector() as selector:
        selector.register(process.stdout, selectors.EVENT_READ)
        while text not in out:
            left = deadline - time.monotonic()
            chunk = os.read(process.stdout.fileno(), 4096) if left > 0 and selector.select(left) else b""
            if not chunk:
                pytest.fail(f"no {text!r} from {process.args[:4]} within {timeout} s: {out!r}")
            out += chunk
    return out


def _finish(process: subprocess.Popen, before: bytes = b"") -> tuple[int, str, str]:
    """Wait (two minutes at most) for the process: its status, whole stdout and stderr."""
    out, err = process.communicate(timeout=120)
    return process.returncode, (before + out).decode(), err.decode()


def _count(pattern: str, text: str) -> int:
    """The number in ``text`` matched by ``pattern``'s group, 0 when it does not occur."""
    found = re.search(pattern, text)
    return int(found.group(1)) if found else 0


def test_two_processes_on_one_folder_share_the_units(tmp_path, single_run):
    """Two runs started together into one folder: each unit is done by exactly one of them, and
    the folder is the one a single run makes, byte for byte."""
    out = tmp_path / "out"
    with folder_lock(out):  # both start-ups wait for it, so that both start the units at once
        processes = [_start(_command(out, "--no-progress")),
                     _start(_command(out, "--no-progress", "--workers", "2", "--backend", "threading"))]
        heads = [_read_until(process, b"-> ") for process in processes]  # their first line: before the lock
    results = [_finish(process, head) for process, head in zip(processes, heads)]
    for status, stdout, stderr in results:
        assert status == 0 and "failed" not in stderr, stdout + stderr
    assert _hashes(out) == single_run  # all 36 shards, each whole and as a single run writes it
    assert not list(out.glob("*.partial")) and not (out / FAILURES_FILE).exists()
    wrote = [_count(r"in (\d+) shards? to", stdout) for _, stdout, _ in results]
    # All 36 exist, so 36 written in all means none was written twice: the units were split.
    assert sum(wrote) == 36 and min(wrote) > 0, wrote
    for (_, stdout, _), written in zip(results, wrote):  # the rest each left to the other (or found done)
        assert written + _count(r"(\d+) shards? (?:was|were) left to another process", stdout) + \
            _count(r"(\d+) shards? (?:was|were) already there", stdout) == 36, stdout


HOLDER = """
import sys, time
from pathlib import Path
from nbvdata.datasets.claims import claim, partial_path
out, name = Path(sys.argv[1]), sys.argv[2]
with claim(out, name) as mine:  # as a generate worker holds a unit while it writes the shard
    partial_path(out / name).write_bytes(b"half a shard")
    print("claimed" if mine else "refused", flush=True)
    time.sleep(300)
"""


def test_a_live_runs_partial_is_left_alone_and_a_killed_ones_is_redone(tmp_path, single_run):
    """A process holding a unit and writing its partial file: a run started meanwhile leaves both
    alone and says so; once the holder is killed, the next run deletes its stale partial and
    does the unit."""
    out = tmp_path / "out"
    config = load_config(SimConfig, SMOKE, COMMAND_SETTINGS)
    held = plan_units(builtin_sources(config.mesh), config)[7].shard_name
    holder = _start([sys.executable, "-c", HOLDER, str(out), held])
    try:
        assert b"claimed" in _read_until(holder, b"claimed")
        partial, = out.glob(f"{held}.*.partial")
        result = subprocess.run(_command(out, "--no-progress"), capture_output=True, text=True, timeout=120)
        assert partial.read_bytes() == b"half a shard" and not (out / held).exists()
        assert result.returncode == 0, result.stderr
        assert "1 shard was left to another process" in result.stdout
        assert "another process is still writing 1 shard into" in result.stdout
        assert len(_hashes(out)) == 35
    finally:
        os.killpg(holder.pid, signal.SIGKILL)
        holder.communicate(timeout=60)
    assert partial.exists()  # the killed holder's, stale now

    result = subprocess.run(_command(out, "--no-progress"), capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "samples in 1 shard to" in result.stdout and "35 shards were already there" in result.stdout
    assert "another process" not in result.stdout
    assert not list(out.glob("*.partial")) and _hashes(out) == single_run


@pytest.mark.parametrize("backend", ["threading", "loky", "dask"])
def test_every_backend_leaves_a_unit_another_process_holds(tmp_path, sources, reference, backend):
    """The workers claim their units themselves, on every backend: one held here is not run, and
    its partial file is not touched."""
    if backend == "dask":
        pytest.importorskip("dask.distributed", reason="the dask extra is not installed: pip install -e '.[dask]'")
    config = _config("generate.workers=2", "generate.runs_per_shard=2", f"generate.backend={backend}")
    held = plan_units(sources, config)[1].shard_name
    with claim(tmp_path, held) as mine:
        assert mine
        partial = partial_path(tmp_path / held)
        partial.write_bytes(b"half a shard")
        report = generate(sources, tmp_path, config)
        assert partial.read_bytes() == b"half a shard" and not (tmp_path / held).exists()
    assert [unit.shard_name for unit in report.others_running] == [held]
    assert len(report.done) == 5 and not report.failures
    _assert_same(_read(tmp_path), {name: arrays for name, arrays in reference.items() if name != held})

    report = generate(sources, tmp_path, config)  # the holder gave up: its unit is done, the partial gone
    assert [r.unit.shard_name for r in report.done] == [held] and not report.others_running
    assert not partial.exists()
    _assert_same(_read(tmp_path), reference)


def test_failures_of_two_runs_into_one_folder_are_merged(tmp_path):
    """Each run lists its own bad meshes; one run's entries do not wipe out another's."""
    out, first, second = tmp_path / "out", tmp_path / "first", tmp_path / "second"
    for folder, name in ((first, "broken_a.obj"), (second, "broken_b.obj")):
        folder.mkdir()
        (folder / name).write_text("v 0 0 0\nthis is not an obj file\nf 1 2 9\n")
    runs = [_start(_command(out, "--no-progress", "--meshes", str(folder))) for folder in (first, second)]
    for process in runs:
        status, stdout, stderr = _finish(process)
        assert status == 1 and "meshes failed" in stderr, stdout + stderr
    lines = (out / FAILURES_FILE).read_text().splitlines()
    assert lines[0] == "mesh\treason" and len(lines) == 3
    assert sorted(Path(line.split("\t")[0]).name for line in lines[1:]) == ["broken_a.obj", "broken_b.obj"]


def test_a_mesh_whose_shards_are_all_there_leaves_failures_tsv(tmp_path, sources):
    """An entry naming a mesh of this run goes once every shard of that mesh is there (fixed);
    entries naming other meshes stay."""
    (tmp_path / FAILURES_FILE).write_text("mesh\treason\n/elsewhere/chair.obj\tMeshError: no faces\n"
                                          f"{sources[0].name}\tRuntimeError: an earlier run\n")
    report = generate(sources[:1], tmp_path, _config("generate.workers=1"))
    assert report.done and not report.failures
    assert (tmp_path / FAILURES_FILE).read_text() == "mesh\treason\n/elsewhere/chair.obj\tMeshError: no faces\n"


# ---------------------------------------------------------------------------------------------
# Exploration moves (episode.explore): the default is today's data, byte for byte

MOVES = ("move", "next_view", "next_pose")


def _file_digests(folder: Path) -> dict[str, str]:
    """sha256 of every file of an output folder (shards and config.yaml)."""
    return {path.name: hashlib.sha256(path.read_bytes()).hexdigest() for path in sorted(folder.iterdir())
            if path.is_file() and not path.name.startswith(".")}


def test_exploration_zero_writes_the_same_bytes_and_datasets_as_no_setting(tmp_path, sources):
    plain, zero = tmp_path / "plain", tmp_path / "zero"
    generate(sources[:2], plain, _config("generate.workers=1"))
    generate(sources[:2], zero, _config("generate.workers=1", "episode.explore=0", "episode.oracle_mix=0"))
    assert _file_digests(plain) == _file_digests(zero) and len(_file_digests(plain)) == 3
    assert "explore" not in (plain / "config.yaml").read_text()
    for path in plain.glob("*.h5"):
        with Shard(path) as shard:
            assert sorted(shard.file) == sorted(DATA)  # no move datasets: today's list
            assert "explore" not in shard.file.attrs["config"] and "policy" not in shard.file.attrs


def test_exploring_shards_record_the_moves_and_match_with_two_workers(tmp_path, sources):
    one, two = tmp_path / "one", tmp_path / "two"
    generate(sources, one, _config("generate.workers=1", "generate.runs_per_shard=2", "episode.explore=0.4"))
    generate(sources, two, _config("generate.workers=2", "generate.runs_per_shard=2", "episode.explore=0.4"))
    assert _file_digests(one) == _file_digests(two)  # the same bytes
    shards = {}
    for path in sorted(one.glob("*.h5")):
        with Shard(path) as shard:
            shards[path.name] = {name: shard[name] for name in (*DATA, *MOVES)}
            assert "explore: 0.4" in shard.file.attrs["config"]
    moves = np.concatenate([arrays["move"] for arrays in shards.values()])
    assert set(moves.tolist()) == {-1, 0, 1}
    for arrays in shards.values():
        moved = arrays["move"] >= 0
        oracle = arrays["move"] == 0
        assert np.array_equal(arrays["next_view"][oracle], arrays["nbv_index"][oracle])
        assert np.array_equal(arrays["next_pose"][moved], arrays["view_poses"][arrays["next_view"][moved]])
        follows = moved[:-1] & (arrays["run"][1:] == arrays["run"][:-1])  # the next sample is the next state
        assert np.array_equal(arrays["last_view"][1:][follows], arrays["next_view"][:-1][follows])
    other = tmp_path / "other"
    generate(sources, other, _config("generate.workers=1", "generate.runs_per_shard=2", "episode.explore=0.4",
                                     "episode.seed=1"))
    assert _file_digests(other).keys() == _file_digests(one).keys() != _file_digests(other)


def test_inspect_shows_the_share_of_exploratory_moves(tmp_path, sources, capsys):
    generate(sources[:1], tmp_path, _config("generate.workers=1", "episode.explore=0.5"))
    assert main(["inspect", str(tmp_path)]) == 0
    line = [line for line in capsys.readouterr().out.splitlines() if line.startswith("moves: ")]
    with Shard(next(tmp_path.glob("*.h5"))) as shard:
        move, off = shard["move"], shard["next_view"] != shard["nbv_index"]
    moved = move >= 0
    assert line == [f"moves: {moved.sum()} moves by rule: oracle {100 * (move == 0).sum() / moved.sum():.1f}%, "
                    f"explore {100 * (move == 1).sum() / moved.sum():.1f}%, policy 0.0%; "
                    f"{100 * off[moved].sum() / moved.sum():.1f}% went elsewhere than the state's label"]


def test_a_shard_that_explores_needs_its_moves(tmp_path, sources):
    generate(sources[:1], tmp_path, _config("generate.workers=1", "episode.explore=0.5"))
    (path,) = tmp_path.glob("*.h5")
    with h5py.File(path, "a") as f:
        del f["next_pose"]
    with pytest.raises(ShardError, match="incomplete shard, missing next_pose"):
        Shard(path)


@pytest.mark.parametrize("argv, message", [
    (["--explore", "1.5"], "argument --explore: must be a number in [0, 1], not '1.5'"),
    (["--oracle-mix", "0.5"], "episode.oracle_mix=0.5 mixes oracle moves into a policy's: pass --policy"),
    (["--policy", "{tmp}/none.pt"], "none.pt: no such checkpoint file; pass a checkpoint written by nbvtrain fit"),
    (["--explore", "0.2"], "holds shards made with other settings (episode.explore)"),
])
def test_exploration_and_policy_errors_are_one_line_and_exit_2(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    if "0.2" in argv:  # a folder of oracle runs
        assert main(["generate", "--out", str(out), "--config", str(SMOKE), "--runs-per-mesh", "1",
                     "--no-progress", "--workers", "1"]) == 0
        capsys.readouterr()
    argv = [a.format(tmp=tmp_path) for a in argv]
    try:
        status = main(["generate", "--out", str(out), "--config", str(SMOKE), "--runs-per-mesh", "1", *argv])
    except SystemExit as stop:  # a value the option's type refuses: argparse's one line
        status = stop.code
    assert status == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err, err


def test_the_card_of_an_exploring_version_says_how_it_moved(tmp_path, sources):
    from nbvdata.datasets.publish import publish

    shards = tmp_path / "explored"
    generate(sources[:1], shards, _config("generate.workers=1", "episode.explore=0.5"))
    card = publish(shards, "explored", "1.0.0", tmp_path / "manifests", about=about()).path.with_suffix(".md").read_text()
    assert "- Exploration: at each move, with probability 0.5 the run moved to a uniformly random view" in card
    assert "moves: " in card and "explore " in card
    for dataset in MOVES:  # present (only the point clouds' and the surface's rows are marked absent)
        (row,) = [line for line in card.splitlines() if line.startswith(f"| `{dataset}` | (N")]
        assert "*(absent in this version)*" not in row
    assert [line.split("`")[1] for line in card.splitlines() if "*(absent in this version)*" in line] == [
        "points", "points_count", "reference_points", "surface"]
    from nbvdata.datasets.card import _reproduce

    config = _config("episode.explore=0.5").dataset_dict()
    content = {"meshes": [{"source": source.name} for source in builtin_sources()], "config": config,
               "shards": [{"runs": [0, 3]}], "root": "../explored"}
    assert _reproduce(content) == ("nbvdata generate --out explored --set views.count=60 --set sensor.width=44 "
                                   "--set sensor.height=36 --set coverage.points=2000 --set episode.runs_per_mesh=3 "
                                   "--set episode.max_scans=4 --set episode.explore=0.5")
