from pathlib import Path

import numpy as np
import pytest

from nbvdata.cli import main


def test_demo_writes_a_png(tmp_path, capsys, monkeypatch):
    import nbvdata.render

    drawn = {}
    render_state = nbvdata.render.render_state
    monkeypatch.setattr(nbvdata.render, "render_state", lambda *a, **k: drawn.update(k) or render_state(*a, **k))
    out = tmp_path / "demo.png"
    assert main(["demo", "--scans", "2", "--set", "views.count=50", "--set", "coverage.points=2000",
                 "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert "scan 2:" in printed and "coverage" in printed
    assert drawn["labels"] == ("last scan", "earlier scans")  # the legend: red is not an NBV here


def test_show_renders_a_saved_grid(tmp_path):
    grid = np.full(32 ** 3, 0.5, dtype=np.float32)
    grid[:1000] = 0.4
    grid[16000:16100] = 0.7
    np.save(tmp_path / "g.npy", grid)
    out = tmp_path / "g.png"
    assert main(["show", str(tmp_path / "g.npy"), "--highlight", "3", "--out", str(out)]) == 0
    assert out.stat().st_size > 1000


def _legend_of_show(argv, monkeypatch) -> list[str]:
    """The legend texts of the picture ``nbvdata show`` draws."""
    import nbvdata.render

    texts, draw_state = [], nbvdata.render.draw_state

    def spy(*args, **kwargs):
        figure = draw_state(*args, **kwargs)
        texts.extend(text.get_text() for legend in figure.legends for text in legend.get_texts())
        return figure

    monkeypatch.setattr(nbvdata.render, "draw_state", spy)
    assert main(["show", *argv]) == 0
    return texts


def test_show_marks_the_views_scanned_and_the_highlighted_one(tmp_path, monkeypatch):
    texts = _legend_of_show(["--views", "3,41", "--highlight", "20", "--set", "views.count=50",
                             "--out", str(tmp_path / "s.png")], monkeypatch)
    assert "scanned views (2)" in texts and "--highlight view (view 20)" in texts, texts
    assert "candidate views (50)" in texts


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
    assert printed.err.startswith(f"nbvdata inspect: error: {tmp_path / 'bad.h5'}: not a readable HDF5 file")
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
