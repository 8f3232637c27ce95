"""The plots say what they show: every line in a legend, every y axis labelled, whole epochs and
scans on the x axes, and a shaded band named."""

import math

import matplotlib.pyplot as plt
import pytest
from matplotlib.figure import Figure

pytest.importorskip("torch", reason="the train extra is not installed: pip install -e '.[train]'")

from nbvtrain.evaluation.evaluate import plot_coverage  # noqa: E402
from nbvtrain.networks.train import curves_figure  # noqa: E402


def _history(epochs: int, gain_ratio: bool = True) -> list[dict]:
    return [{"epoch": e, "train_loss": 1 / (e + 1), "val_loss": 1.2 / (e + 1), "val_mae": 0.3 / e,
             "val_angle_deg": 40.0 - e, "val_gain_ratio": 0.5 + 0.1 * e if gain_ratio else math.nan, "seconds": 1.0}
            for e in range(1, epochs + 1)]


def _legend_texts(figure: Figure) -> list[str]:
    return [text.get_text() for axes in figure.axes if axes.get_legend() for text in axes.get_legend().get_texts()]


def _ticks_shown(axes) -> list[float]:
    low, high = axes.get_xlim()
    return [tick for tick in axes.get_xticks() if low <= tick <= high]


@pytest.mark.parametrize("gain_ratio", [True, False], ids=["scored data", "imported data"])
def test_learning_curves_label_every_line_and_axis_and_tick_whole_epochs(gain_ratio):
    figure = curves_figure(_history(3, gain_ratio), "nbvnet-3-3")
    figure.canvas.draw()
    try:
        lines = [line for axes in figure.axes for line in axes.get_lines()]
        assert len(lines) == (5 if gain_ratio else 4)
        legend = _legend_texts(figure)
        assert sorted(legend) == sorted(line.get_label() for line in lines)  # every line, each once
        assert all(axes.get_ylabel() for axes in figure.axes), [axes.get_ylabel() for axes in figure.axes]
        for axes in figure.axes:
            ticks = _ticks_shown(axes)
            assert ticks and all(tick == int(tick) for tick in ticks), ticks  # was 1.0, 1.25, ... 3.0
    finally:
        plt.close(figure)


def test_one_epoch_of_learning_curves_is_drawn_as_points():
    """A 1-epoch run: every line is one point, so each has a marker, and the x axis spans that epoch."""
    figure = curves_figure(_history(1), "nbvnet-3-3")
    try:
        lines = [line for axes in figure.axes for line in axes.get_lines()]
        assert lines and all(line.get_marker() == "o" for line in lines)
        assert all(axes.get_xlim() == (0.5, 1.5) for axes in figure.axes)
    finally:
        plt.close(figure)


def _row(planner: str, start: int, scan: int, coverage: float) -> dict:
    return {"mesh": "mug", "planner": planner, "start": start, "scan": scan, "coverage": coverage}


def _coverage_figure(rows, tmp_path, monkeypatch) -> dict:
    seen, save = {}, Figure.savefig

    def spy(figure, *args, **kwargs):
        seen.update(legend=_legend_texts(figure), title=figure.axes[0].get_title())
        return save(figure, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", spy)
    plot_coverage(rows, tmp_path)
    return seen


def test_coverage_plots_name_the_shaded_band(tmp_path, monkeypatch):
    rows = [_row(planner, start, scan, 0.1 * scan + 0.05 * start + (0.1 if planner == "b" else 0))
            for planner in ("a", "b") for start in range(3) for scan in (1, 2, 3)]
    seen = _coverage_figure(rows, tmp_path, monkeypatch)
    assert seen["legend"] == ["a", "b", "shaded: lowest to highest of 3 starts"]
    assert seen["title"] == "mug: mean of 3 starts"
    one = [row for row in rows if row["start"] == 0]  # one start: no band, nothing to say
    seen = _coverage_figure(one, tmp_path, monkeypatch)
    assert seen["legend"] == ["a", "b"] and seen["title"] == "mug"


def test_the_x_axis_spans_the_scans_made_and_a_floor_beyond_them_is_named(tmp_path, monkeypatch):
    rows = [_row("a", 0, scan, 0.1 * scan) for scan in range(1, 11)]
    limits, axes_set = {}, plt.Axes.set

    def spy(axes, **kwargs):
        limits.update(kwargs)
        return axes_set(axes, **kwargs)

    monkeypatch.setattr(plt.Axes, "set", spy)
    far = [{"mesh": "mug", "start": 0, "cover_size": 57}]
    seen = {}
    save = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda figure, *a, **k: (seen.update(legend=_legend_texts(figure)),
                                                                      save(figure, *a, **k)))
    plot_coverage(rows, tmp_path, far)
    assert limits["xlim"] == (0.5, 10.5)
    assert seen["legend"] == ["a", "floor: fewest scans to all observable, 58 (beyond the plot)"]
    plot_coverage(rows, tmp_path, [{"mesh": "mug", "start": 0, "cover_size": 6}])
    assert seen["legend"] == ["a", "floor: fewest scans to all observable"] and limits["xlim"] == (0.5, 10.5)
