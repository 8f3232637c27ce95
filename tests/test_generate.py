"""The generator job: same arrays whatever the workers or backend, resume after a kill,
bad meshes reported while the others go on."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from nbvdata.cli import main
from nbvdata.config import SimConfig, load_config
from nbvdata.generate import FAILURES_FILE, builtin_sources, generate, mesh_sources, plan_units
from nbvdata.mesh import sha256_file
from nbvdata.shapes import builtin_object
from nbvdata.shards import Shard

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


def test_the_split_into_shards_does_not_change_the_samples(tmp_path, sources, reference):
    generate(sources, tmp_path, _config("generate.workers=1"))  # one shard per mesh
    assert len(list(tmp_path.glob("*.h5"))) == 3
    _assert_same(_per_mesh(_read(tmp_path)), _per_mesh(reference))


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


def test_mesh_lists_resolve_relative_to_the_list(tmp_path):
    meshes = tmp_path / "meshes"
    _write_meshes(meshes)
    listing = tmp_path / "list.txt"
    listing.write_text("# two files\nmeshes/mug.obj\n\nmeshes/broken.obj  # bad\n")
    sources, failures = mesh_sources(listing)
    assert [s.name for s in sources] == ["mug.obj", "broken.obj"] and not failures


def _sha256s(folder: Path) -> dict[str, str]:
    return {path.name: sha256_file(path) for path in sorted(folder.glob("*.h5"))}


def test_shards_are_byte_identical_without_the_cpus_vector_extensions(tmp_path):
    """Published manifests pin shards by sha256, so a user's CPU must not change a bit: the same
    job with numpy's AVX-512 loops and numba's host-specific code switched off gives the same files."""
    here, generic = tmp_path / "here", tmp_path / "generic"
    subprocess.run(_command(here, "--no-progress"), check=True, capture_output=True)
    env = os.environ | {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR AVX512F AVX512CD AVX512_SKX "
                        "AVX512_CLX AVX512_CNL", "NUMBA_CPU_NAME": "generic", "NUMBA_CACHE_DIR": str(tmp_path / "jit")}
    result = subprocess.run(_command(generic, "--no-progress"), capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stderr
    assert len(_sha256s(here)) == 36 and _sha256s(here) == _sha256s(generic)


def test_the_readme_dataset_is_the_published_builtin_shapes(tmp_path, capsys):
    """README's main command reproduces manifests/builtin-shapes-1.0.0 byte for byte. If this fails
    after a deliberate change to generation, publish the new data as a new version (README:
    "Versions are immutable") and point this test at it."""
    manifest = Path(__file__).resolve().parents[1] / "manifests" / "builtin-shapes-1.0.0.json"
    assert main(["generate", "--out", str(tmp_path / "nbv_dataset"), "--no-progress"]) == 0
    assert main(["verify", str(manifest), "--root", str(tmp_path / "nbv_dataset")]) == 0, capsys.readouterr().out
