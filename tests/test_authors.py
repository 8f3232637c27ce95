"""Importing the authors' dataset: derived runs, exact round trips, zip = npy, resume, one-line
errors, and the first rows of the real files when they are there."""

import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import DATASET
from numpy.lib import format as npy_format

from nbvdata.cli import main
from nbvdata.datasets import authors as legacy
from nbvdata.datasets.authors import ROW, AuthorsDataError, import_legacy
from nbvdata.schema.shards import OPTIONAL, Shard

KNOWN = [[1000, 3000, 3000, 5000], [2000], [500, 600, 9000], [4000, 4001], [100, 200, 300, 400, 30000]]
"""Known voxels of each state of each run: runs of 4, 1, 3, 2 and 5 steps (3000 twice: a scan
that adds nothing keeps the run going)."""
VALUES = np.array([0.1192, 0.307692, 0.4, 0.608696, 0.7, 0.971, 0.123456789])
DIRECTIONS = np.array([[0, 0, 1], [1, 0, 0], [0, -1, 0.2], [-1, 1, 0.5], [0.3, 0.3, 0.9]], dtype=np.float64)


def _synthetic(rng) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """grids (15, ROW) float64, poses (15, 6), and the runs (15,) and steps (15,) they hold."""
    grids, runs, steps = [], [], []
    for run, counts in enumerate(KNOWN):
        grid, order = np.full(ROW, 0.5), rng.permutation(ROW)
        for step, count in enumerate(counts, start=1):
            grid = grid.copy()
            grid[order[:count]] = rng.choice(VALUES, count)  # more known voxels, some values change
            grids.append(grid)
            runs.append(run)
            steps.append(step)
    count = len(grids)
    units = DIRECTIONS / np.linalg.norm(DIRECTIONS, axis=1, keepdims=True)
    positions = 0.4 * units[np.arange(count) % len(units)]
    positions[5] += 3e-8  # the same view as row 0, after rounding to 1e-6
    poses = np.concatenate([positions, rng.uniform(-3, 3, (count, 3))], axis=1)
    return np.array(grids), poses, np.array(runs), np.array(steps)


def _write(folder: Path, grids: np.ndarray, poses: np.ndarray, zipped: bool = False) -> tuple[Path, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for stem, array in (("dataset_volumes_regression", grids), ("dataset_pose", poses)):
        path = folder / f"{stem}.npy"
        np.save(path, array)
        if zipped:
            with zipfile.ZipFile(folder / f"{stem}.zip", "w", zipfile.ZIP_DEFLATED) as archive:
                archive.write(path, arcname=path.name)
            path.unlink()
            path = folder / f"{stem}.zip"
        paths.append(path)
    return paths[0], paths[1]


def _read(out: Path) -> tuple[dict[str, np.ndarray], list[dict], dict[str, np.ndarray]]:
    """Every shard of ``out`` in order: per-sample arrays concatenated (grids decoded), each
    shard's attributes, and the last shard's per-shard arrays."""
    columns, attrs = {}, []
    for path in sorted(out.glob("legacy-*.h5")):
        with Shard(path) as shard:
            assert not [name for name in OPTIONAL if shard.has(name)]  # nothing invented
            attrs.append(dict(shard.file.attrs, codes=shard.file["grids"][()]))
            for name in ("nbv_index", "nbv_pose", "nbv_position", "run", "step"):
                columns.setdefault(name, []).append(shard[name])
            columns.setdefault("grids", []).append(shard.grids().reshape(len(shard), ROW))
            columns.setdefault("codes", []).append(shard["grids"].reshape(len(shard), ROW))
            shared = {"view_positions": shard["view_positions"], "grid_palette": shard.palette}
    return {name: np.concatenate(parts) for name, parts in columns.items()}, attrs, shared


@pytest.mark.parametrize("block_rows", [2, 32])
def test_synthetic_import_derives_the_runs_and_round_trips_exactly(tmp_path, rng, monkeypatch, block_rows):
    monkeypatch.setattr(legacy, "BLOCK_ROWS", block_rows)  # runs must not depend on the blocks
    grids, poses, runs, steps = _synthetic(rng)
    volumes_path, poses_path = _write(tmp_path / "data", grids, poses)
    report = import_legacy(volumes_path, poses_path, tmp_path / "out", rows_per_shard=4, show_progress=False)
    assert report.rows == 15 and report.written == [f"legacy-{i:05d}.h5" for i in range(4)]
    assert report.run_lengths == [len(counts) for counts in KNOWN]

    data, attrs, shared = _read(tmp_path / "out")
    assert np.array_equal(data["run"], runs) and np.array_equal(data["step"], steps)
    assert np.array_equal(data["grids"], grids.astype(np.float32))
    assert np.array_equal(data["grids"] == 0.5, grids == 0.5) and np.array_equal(data["codes"] == 0, grids == 0.5)
    assert np.array_equal(data["nbv_pose"], poses)
    unit = poses[:, :3] / np.linalg.norm(poses[:, :3], axis=1, keepdims=True)
    assert data["nbv_position"].dtype == np.float32 and np.array_equal(data["nbv_position"], unit.astype(np.float32))
    views, keys = shared["view_positions"], np.round(shared["view_positions"], 6)
    assert len(views) == len(DIRECTIONS) and np.array_equal(keys, np.unique(keys, axis=0))  # distinct, sorted
    assert np.allclose(views[data["nbv_index"]], poses[:, :3], atol=1e-6, rtol=0)
    assert data["nbv_index"][5] == data["nbv_index"][0]

    assert [list(a["rows"]) for a in attrs] == [[0, 4], [4, 8], [8, 12], [12, 15]]
    assert [list(a["runs"]) for a in attrs] == [[0, 1], [1, 3], [3, 5], [4, 5]]  # run 4 spans two shards
    assert [a["source"] for a in attrs][1] == f"legacy: {legacy.DATASET} dataset_volumes_regression.npy rows 4-8"
    config = yaml.safe_load(attrs[0]["config"])
    assert config["grid"]["size"] == 32 and config["views"]["count"] == 5 and config["views"]["radius"] == 0.4
    assert attrs[0]["meshes"] == "[]" and [a["samples"] for a in attrs] == [4, 4, 4, 3]


def test_zip_and_npy_give_identical_shards(tmp_path, rng):
    grids, poses, _, _ = _synthetic(rng)
    for zipped in (False, True):
        volumes_path, poses_path = _write(tmp_path / f"data{zipped}", grids, poses, zipped)
        import_legacy(volumes_path, poses_path, tmp_path / f"out{zipped}", rows_per_shard=8, show_progress=False)
    names = sorted(p.name for p in (tmp_path / "outFalse").iterdir())
    assert names == ["legacy-00000.h5", "legacy-00001.h5"] == sorted(p.name for p in (tmp_path / "outTrue").iterdir())
    for name in names:
        assert (tmp_path / "outFalse" / name).read_bytes() == (tmp_path / "outTrue" / name).read_bytes()


def test_resume_skips_complete_shards_and_refuses_other_imports(tmp_path, rng):
    grids, poses, _, _ = _synthetic(rng)
    volumes_path, poses_path = _write(tmp_path / "data", grids, poses)
    out = tmp_path / "out"
    import_legacy(volumes_path, poses_path, out, rows_per_shard=4, show_progress=False)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    (out / "legacy-00002.h5").unlink()
    (out / "legacy-00003.h5.partial").write_bytes(b"left by a kill")
    report = import_legacy(volumes_path, poses_path, out, rows_per_shard=4, show_progress=False)
    assert report.written == ["legacy-00002.h5"] and len(report.skipped) == 3 and len(report.run_lengths) == 5
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    with pytest.raises(AuthorsDataError, match=r"legacy-00000\.h5: holds .*rows 0-4.*rows 0-6.*new --out folder"):
        import_legacy(volumes_path, poses_path, out, rows_per_shard=6, show_progress=False)


def test_limit_and_more_than_256_values(tmp_path, rng):
    grids, poses, _, _ = _synthetic(rng)
    grids[1, np.flatnonzero(grids[1] != 0.5)[:400]] = np.linspace(0.01, 0.45, 400)  # > 256 values: uint16 codes
    volumes_path, poses_path = _write(tmp_path / "data", grids, poses)
    report = import_legacy(volumes_path, poses_path, tmp_path / "out", rows_per_shard=4, limit=6, show_progress=False)
    assert report.rows == 6 and report.run_lengths == [4, 1, 1]
    data, attrs, _ = _read(tmp_path / "out")
    assert [list(a["rows"]) for a in attrs] == [[0, 4], [4, 6]]
    assert attrs[0]["codes"].dtype == np.uint16 and attrs[1]["codes"].dtype == np.uint8
    assert np.array_equal(data["grids"], grids[:6].astype(np.float32))


def test_cli_imports_and_inspect_reads_the_shards(tmp_path, rng, capsys):
    grids, poses, _, _ = _synthetic(rng)
    volumes_path, poses_path = _write(tmp_path / "data", grids, poses, zipped=True)
    out = tmp_path / "out"
    assert main(["import-legacy", "--volumes", str(volumes_path), "--poses", str(poses_path), "--out", str(out),
                 "--rows-per-shard", "8"]) == 0
    printed = capsys.readouterr().out
    assert "imported 15 rows into 2 shards" in printed and "(5 runs)" in printed and "peak memory" in printed
    assert main(["inspect", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "2 shards, 15 samples, 1 mesh, 5 candidate views" in printed
    line = next(line for line in printed.splitlines() if line.startswith("legacy: nbv-regression-2019"))
    assert line.split()[-6:] == ["2", "5", "15", "3.0", "-", "-"]  # shards, runs, samples, scans/run, no coverage
    assert "gain of the NBV: median -" in printed
    png = tmp_path / "sample.png"
    assert main(["show", str(out / "legacy-00001.h5"), "--index", "2", "--out", str(png)]) == 0
    assert png.stat().st_size > 1000 and f"wrote {png}" in capsys.readouterr().out


def _zip_of(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return path


@pytest.mark.parametrize("case, message", [
    ("missing", r"missing\.zip: no such file: pass the authors' dataset_volumes_regression\.npy"),
    ("zip without npy", r"holds no \.npy files \(readme\.txt\), expected one"),
    ("broken zip", r"not a readable zip file .*download it again"),
    ("not npy", r"not a \.npy array"),
    ("wrong shape", r"holds a C-order \(15, 100\) float64 array, expected C-order float64 \(N, 32768\) grids"),
    ("wrong dtype", r"\(15, 32768\) float32 array, expected C-order float64"),
    ("fortran", r"holds a Fortran-order \(15, 32768\) float64 array"),
    ("row counts", r"holds 15 grids but .*dataset_pose\.npy holds 14 poses: pass the volumes and poses of the same"),
    ("truncated npy", r"truncated: the header promises 15 rows, the data end in row 9"),
    ("truncated in zip", r"dataset_volumes_regression\.zip:v\.npy: truncated"),
])
def test_bad_inputs_give_one_line_errors_and_exit_2(tmp_path, rng, capsys, case, message):
    grids, poses, _, _ = _synthetic(rng)
    volumes_path, poses_path = _write(tmp_path, grids, poses)
    raw = volumes_path.read_bytes()
    if case == "missing":
        volumes_path = tmp_path / "missing.zip"
    elif case == "zip without npy":
        volumes_path = _zip_of(tmp_path / "v.zip", {"readme.txt": b"nothing"})
    elif case == "broken zip":
        _zip_of(tmp_path / "v.zip", {"v.npy": raw})
        (tmp_path / "broken.zip").write_bytes((tmp_path / "v.zip").read_bytes()[:100_000])
        volumes_path = tmp_path / "broken.zip"
    elif case == "not npy":
        volumes_path.write_text("x,y,z\n")
    elif case == "wrong shape":
        np.save(volumes_path, grids[:, :100])
    elif case == "wrong dtype":
        np.save(volumes_path, grids.astype(np.float32))
    elif case == "fortran":
        np.save(volumes_path, np.asfortranarray(grids))
    elif case == "row counts":
        np.save(poses_path, poses[:-1])
    elif case == "truncated npy":
        volumes_path.write_bytes(raw[:len(raw) - 6 * ROW * 8 + 5])
    elif case == "truncated in zip":
        volumes_path = _zip_of(tmp_path / "dataset_volumes_regression.zip", {"v.npy": raw[:len(raw) // 2]})
    code = main(["import-legacy", "--volumes", str(volumes_path), "--poses", str(poses_path),
                 "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and err.startswith("nbvdata import-legacy: error: "), err
    assert re.search(message, err), err
    assert not list(tmp_path.glob("out/*.h5"))


@pytest.mark.parametrize("flag", ["--rows-per-shard", "--limit"])
def test_bad_counts_are_usage_errors(tmp_path, capsys, flag):
    with pytest.raises(SystemExit) as done:
        main(["import-legacy", "--volumes", "v.zip", "--poses", "p.zip", "--out", str(tmp_path), flag, "0"])
    assert done.value.code == 2 and f"argument {flag}: must be a whole number >= 1, not '0'" in capsys.readouterr().err


@pytest.fixture
def authors_dataset() -> Path:
    if not DATASET.exists():
        pytest.skip(f"authors' dataset not found at {DATASET} (shared data is not part of a clone)")
    return DATASET


def test_first_rows_of_the_authors_dataset(tmp_path, capsys, authors_dataset):
    rows, out = 600, tmp_path / "out"
    volumes_zip, poses_zip = authors_dataset / "dataset_volumes_regression.zip", authors_dataset / "dataset_pose.zip"
    assert main(["import-legacy", "--volumes", str(volumes_zip), "--poses", str(poses_zip), "--out", str(out),
                 "--limit", str(rows), "--rows-per-shard", "256", "--no-progress"]) == 0
    with zipfile.ZipFile(poses_zip) as archive, archive.open("dataset_pose.npy") as f:
        poses = np.load(f)
    with zipfile.ZipFile(volumes_zip) as archive, archive.open("dataset_volumes_regression.npy") as f:
        assert npy_format.read_magic(f) == (1, 0)
        shape, _, dtype = npy_format.read_array_header_1_0(f)
        grids = np.frombuffer(f.read(rows * ROW * 8), dtype=dtype).reshape(rows, ROW)
    assert shape == (len(poses), ROW) == (15166, ROW)

    data, attrs, shared = _read(out)
    assert len(attrs) == 3 and [list(a["rows"]) for a in attrs][-1] == [512, 600]
    assert np.abs(data["grids"] - grids).max() < 1e-3
    assert np.array_equal(data["grids"] == 0.5, grids == 0.5) and np.array_equal(data["codes"] == 0, grids == 0.5)
    assert np.array_equal(data["nbv_pose"], poses[:rows])
    assert len(shared["view_positions"]) == 263  # the whole dataset's views, whatever --limit
    assert np.allclose(shared["view_positions"][data["nbv_index"]], poses[:rows, :3], atol=1e-6, rtol=0)
    assert np.allclose(np.linalg.norm(data["nbv_position"], axis=1), 1, atol=1e-6)
    known = grids != 0.5
    starts = np.concatenate([[True], (known[:-1] & ~known[1:]).any(axis=1)])
    assert np.array_equal(data["run"], np.cumsum(starts) - 1)
    assert 2 <= data["step"].max() <= 19 and data["step"][0] == 1
    capsys.readouterr()
    assert main(["inspect", str(out)]) == 0
    assert f"3 shards, {rows} samples, 1 mesh, 263 candidate views" in capsys.readouterr().out
