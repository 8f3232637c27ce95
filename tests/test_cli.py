import numpy as np
import pytest

from nbvdata.cli import main


def test_demo_writes_a_png(tmp_path, capsys, monkeypatch):
    import nbvdata.view.render

    drawn = {}
    render_state = nbvdata.view.render.render_state
    monkeypatch.setattr(nbvdata.view.render, "render_state", lambda *a, **k: drawn.update(k) or render_state(*a, **k))
    out = tmp_path / "demo.png"
    assert main(["demo", "--scans", "2", "--set", "views.count=50", "--set", "coverage.points=2000",
                 "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert "scan 2:" in printed and "coverage" in printed
    assert len(drawn["scanned"]) == 2 and drawn.get("highlight") is None  # scans green; red is the next view only


def test_picture_titles_say_of_which_surface_the_coverage_is(tmp_path, capsys, monkeypatch):
    """Issue 58: a title's coverage is of the whole surface or of its observable part, and says so:
    demo's of both (the figures of its last scan's line), a shard sample's of the observable (the
    shard's coverage and gains)."""
    from pathlib import Path

    import nbvdata.view.render

    titles = []
    render_state = nbvdata.view.render.render_state
    monkeypatch.setattr(nbvdata.view.render, "render_state", lambda *a, **k: titles.append(k["title"]) or
                        render_state(*a, **k))
    smoke = str(Path(__file__).resolve().parents[1] / "configs" / "smoke.yaml")
    assert main(["demo", "--shape", "mug", "--scans", "2", "--config", smoke, "--out", str(tmp_path / "d.png")]) == 0
    last = capsys.readouterr().out.splitlines()[-2].split()  # scan 2: ... coverage T% observable O% ...
    total, observable = last[last.index("coverage") + 1], last[last.index("observable") + 1]
    assert titles[-1].endswith(f"2 scans, coverage {total} of the whole surface, {observable} of the observable")
    assert main(["generate", "--config", smoke, "--runs-per-mesh", "1", "--out", str(tmp_path / "s"),
                 "--no-progress"]) == 0
    shard = sorted((tmp_path / "s").glob("*.h5"))[0]
    assert main(["show", str(shard), "--index", "1", "--out", str(tmp_path / "s.png")]) == 0
    assert "% of the observable surface, overlap " in titles[-1] and ", observable coverage " in titles[-1]


def _grid(seed: int = 0) -> np.ndarray:
    grid = np.full(32 ** 3, 0.5, dtype=np.float32)
    grid[:1000] = 0.4
    grid[16000 + 100 * seed:16100 + 100 * seed] = 0.7
    return grid.reshape(32, 32, 32)


def test_show_renders_a_saved_grid(tmp_path, monkeypatch):
    import nbvdata.view.render

    drawn = []
    render_state = nbvdata.view.render.render_state
    monkeypatch.setattr(nbvdata.view.render, "render_state", lambda grid, *a, **k: drawn.append(grid) or
                        render_state(grid, *a, **k))
    np.save(tmp_path / "g.npy", _grid())
    out = tmp_path / "g.png"
    assert main(["show", str(tmp_path / "g.npy"), "--highlight", "3", "--out", str(out)]) == 0
    assert out.stat().st_size > 1000
    np.save(tmp_path / "batch.npy", np.stack([_grid(0), _grid(1), _grid(2)]).astype(np.float64))  # (B, 32, 32, 32)
    assert main(["show", str(tmp_path / "batch.npy"), "--index", "2", "--out", str(out)]) == 0
    assert np.array_equal(drawn[0], _grid()) and np.array_equal(drawn[1], _grid(2)) and drawn[1].dtype == np.float32


SHOW_BAD_GRIDS = {
    "NaN": (np.where(np.arange(32 ** 3) == 5, np.nan, 0.5).reshape(32, 32, 32), "grid holds 1 NaN values of 32768"),
    "integers": (np.ones((32, 32, 32), dtype=np.int64), "grid has dtype int64, expected float occupancy probabilities"),
    "out of range": (np.full((32, 32, 32), 7.0), "grid holds values in [7, 7], outside [0, 1]"),
    "(64, 32, 16)": (np.full((64, 32, 16), 0.5),
                     "grid has shape (64, 32, 16), expected (32, 32, 32) or (B, 32, 32, 32)"),
    "flat": (np.full(32 ** 3, 0.5), "grid has shape (32768,), expected (32, 32, 32)"),
    "16^3": (np.full((16, 16, 16), 0.5), "grid has shape (16, 16, 16), expected (32, 32, 32)"),
}


@pytest.mark.parametrize("case", SHOW_BAD_GRIDS)
def test_show_refuses_what_predict_refuses(case, tmp_path, capsys):
    grid, message = SHOW_BAD_GRIDS[case]
    np.save(tmp_path / "g.npy", grid)
    assert main(["show", str(tmp_path / "g.npy"), "--out", str(tmp_path / "g.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"nbvdata show: error: {tmp_path / 'g.npy'}: {message}"), err
    assert len(err.splitlines()) == 1 and not (tmp_path / "g.png").exists()


def test_show_checks_grids_with_predicts_own_function():
    """One check for both commands: nbvtrain's API uses nbvdata's check_grids (nbvdata imports no nbvtrain)."""
    import nbvdata.core.userarrays
    import nbvtrain.networks.predict

    assert nbvtrain.networks.predict.check_grids is nbvdata.core.userarrays.check_grids
    assert nbvtrain.networks.predict.GridError is nbvdata.core.userarrays.GridError


def test_show_names_a_file_that_is_no_plain_array(tmp_path, capsys):
    (tmp_path / "g.npy").write_text("0.5 0.5\n")
    assert main(["show", str(tmp_path / "g.npy"), "--out", str(tmp_path / "g.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"nbvdata show: error: {tmp_path / 'g.npy'}: not a numpy array file (.npy): write it with np.save"
    np.save(tmp_path / "b.npy", np.stack([_grid(), _grid()]))
    assert main(["show", str(tmp_path / "b.npy"), "--index", "2", "--out", str(tmp_path / "g.png")]) == 2
    assert capsys.readouterr().err.strip() == (f"nbvdata show: error: --index 2: {tmp_path / 'b.npy'} holds 2 grids "
                                               "(0..1)")


def _legend_of_show(argv, monkeypatch) -> list[str]:
    """The legend texts of the picture ``nbvdata show`` draws."""
    import nbvdata.view.render

    texts, draw_state = [], nbvdata.view.render.draw_state

    def spy(*args, **kwargs):
        figure = draw_state(*args, **kwargs)
        texts.extend(text.get_text() for legend in figure.legends for text in legend.get_texts())
        return figure

    monkeypatch.setattr(nbvdata.view.render, "draw_state", spy)
    assert main(["show", *argv]) == 0
    return texts


def test_show_marks_the_views_scanned_and_the_highlighted_one(tmp_path, monkeypatch):
    texts = _legend_of_show(["--views", "3,41", "--highlight", "20", "--set", "views.count=50",
                             "--out", str(tmp_path / "s.png")], monkeypatch)
    assert "scanned views (2, numbered in scan order)" in texts and "--highlight view (view 20)" in texts, texts
    assert "candidate views (50)" in texts


def test_show_of_a_shard_sample_draws_the_views_its_run_scanned(tmp_path, monkeypatch):
    from nbvdata.schema.shards import Shard

    assert main(["generate", "--config", "configs/smoke.yaml", "--runs-per-mesh", "1", "--out", str(tmp_path / "d"),
                 "--no-progress"]) == 0
    shard = sorted((tmp_path / "d").glob("*.h5"))[0]
    with Shard(shard) as opened:
        index = int(np.flatnonzero(opened["step"] == 3)[0])
    texts = _legend_of_show([str(shard), "--index", str(index), "--out", str(tmp_path / "s.png")], monkeypatch)
    assert "scanned by this state (3, numbered in scan order)" in texts and "runner-up candidates" in texts, texts


def test_a_highlight_out_of_range_names_highlight(tmp_path, capsys):
    assert main(["show", "--views", "3", "--highlight", "9999", "--set", "views.count=50",
                 "--out", str(tmp_path / "s.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("nbvdata show: error: --highlight: indices [9999] out of range") and "--views" not in err


@pytest.mark.parametrize("argv, message", [
    (["generate", "--meshes", "nope.obj"], "nope.obj: no such file or folder; pass a folder of mesh files, one mesh "
     "file (.obj, .ply, .off, .stl, .glb, .gltf) or a .txt list of mesh files"),
    (["demo", "--set", "views.cont=3"], "did you mean 'views.count'"),
    (["demo", "--mesh", "missing.obj"], "no such file"),
    (["show", "nothing.npy"], "no such file"),
    (["show", "--views", "0,9999"], "out of range"),
])
def test_user_errors_are_one_line_and_exit_2(argv, message, capsys, tmp_path):
    assert main(argv + ["--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_inspect_reports_unreadable_shards_before_printing_anything(tmp_path, capsys):
    for name in ("bad.h5", "worse.h5"):
        (tmp_path / name).write_text("not a shard\n")
    assert main(["inspect", str(tmp_path / "bad.h5")]) == 2
    printed = capsys.readouterr()
    assert printed.out == ""  # no empty table
    assert printed.err.startswith(f"nbvdata inspect: error: {tmp_path / 'bad.h5'}: not an HDF5 file (a text file), "
                                  "so not a shard")
    assert "delete" not in printed.err  # no shard, so none to delete and regenerate
    assert len(printed.err.splitlines()) == 1
    assert main(["inspect", str(tmp_path)]) == 2
    printed = capsys.readouterr()
    assert printed.out == "" and printed.err.strip().endswith("(and 1 other unreadable shard)")


def test_help_describes_the_workflow_and_every_command(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    assert "generate -> inspect -> publish -> verify" in text and "nbvtrain fit" in text
    listed = text.split("commands:", 1)[1]
    for command in ("generate", "inspect", "publish", "verify", "show", "demo", "import-legacy"):
        assert f"\n    {command} " in listed or f"\n    {command}\n" in listed, command
    example = text.split("example", 1)[1]
    assert "nbvdata generate --out nbv_dataset" in example and "nbvdata verify manifests/" in example
