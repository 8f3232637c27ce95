"""Voxel rendering draws exactly the faces not hidden by a filled neighbour; the pictures have a
legend and no blank third."""

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.image import imread

from nbvdata.core.config import ViewConfig
from nbvdata.core.views import view_sphere
from nbvdata.view.render import CUT_AWAY, UNKNOWN, draw_state, enclosed, exposed_faces, render_state, tighten


@pytest.mark.parametrize("block, faces", [((1, 1, 1), 6), ((2, 1, 1), 10), ((3, 3, 3), 54)])
def test_exposed_faces_of_a_block(block, faces):
    filled = np.zeros((6, 6, 6), dtype=bool)
    filled[1:1 + block[0], 2:2 + block[1], 0:block[2]] = True
    colors = np.ones((6, 6, 6, 4))
    quads, face_colors = exposed_faces(filled, colors)
    assert quads.shape == (faces, 4, 3) and face_colors.shape == (faces, 4)
    edges = np.linalg.norm(np.diff(quads, axis=1, append=quads[:, :1]), axis=2)
    assert np.allclose(edges, 1.0)  # unit squares
    low, high = quads.reshape(-1, 3).min(axis=0), quads.reshape(-1, 3).max(axis=0)
    assert np.array_equal(low, [1, 2, 0]) and np.array_equal(high - low, block)  # on the block's hull


def _grid() -> np.ndarray:
    grid = np.full((16, 16, 16), 0.4, dtype=np.float32)  # free
    grid[4:12, 4:12, 4:12] = 0.5  # unknown
    grid[6:10, 6:10, 6:10] = 0.7  # occupied
    return grid


def _shell() -> np.ndarray:
    """An object seen all round: an occupied shell, its inside unknown (no scan reaches it)."""
    grid = np.full((16, 16, 16), 0.4, dtype=np.float32)
    grid[3:13, 3:13, 3:13] = 0.7
    grid[4:12, 4:12, 4:12] = 0.5
    return grid


def _legend(fig) -> list[str]:
    return [text.get_text() for legend in fig.legends for text in legend.get_texts()]


def _drawn_colours(fig) -> np.ndarray:
    """(F, 4) RGBA of the voxel faces drawn."""
    (faces,) = fig.axes[0].collections[:1]
    return faces.get_facecolor()


def test_the_legend_names_every_colour_and_arrow():
    views = view_sphere(ViewConfig(count=40))
    grid = _grid()
    grid[4:12, 4:12, 4:12][grid[4:12, 4:12, 4:12] == 0.5] = 0.4
    grid[5:11, 5:11, 5:11][grid[5:11, 5:11, 5:11] == 0.4] = 0.5  # one layer of unknown: none is enclosed
    fig = draw_state(grid, 0.3, views, highlight=3, others=[5, 7])
    texts = _legend(fig)
    plt.close(fig)
    assert texts == ["occupied (64 voxels)", "unknown (152)", "free (3880, not drawn)", "candidate views (40)",
                     "next-best-view (view 3, behind the object)", "runner-up candidates",
                     "views drawn at 90% of their distance (directions exact)"]
    fig = draw_state(_grid(), 0.3, views)
    texts = [text.get_text() for legend in fig.legends for text in legend.get_texts()]
    plt.close(fig)
    assert len(texts) == 6 and not any("view (" in text for text in texts)  # no arrows, no arrow entries


def _dots(fig) -> np.ndarray:
    """(D, 3) every dot drawn (the candidate views, in front of the grid's centre and behind it)."""
    from mpl_toolkits.mplot3d.art3d import Path3DCollection

    return np.concatenate([np.stack(c._offsets3d, axis=1) for c in fig.axes[0].collections
                           if isinstance(c, Path3DCollection)])


def _arrow_colours(fig) -> list[tuple]:
    """The RGB of every arrow (quiver) drawn, the orientation triad's included."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    return [tuple(np.round(c.get_color()[0][:3], 3)) for c in fig.axes[0].collections
            if isinstance(c, Line3DCollection)]


def test_one_colour_one_meaning_in_every_picture():
    """Red the next view, orange the runner-ups, green the scanned views, whoever draws them;
    an x, y, z triad; the legend names each."""
    from matplotlib.colors import to_rgb

    from nbvdata.view.render import AXES_COLOUR, NEXT, RUNNER_UP, SCANNED

    views = view_sphere(ViewConfig(count=40))
    fig = draw_state(_grid(), 0.3, views, highlight=3, others=[5, 7], scanned=[0, 1, 2])
    colours, texts = _arrow_colours(fig), _legend(fig)
    labels = [text.get_text() for text in fig.axes[0].texts]
    plt.close(fig)
    rgb = lambda colour: tuple(np.round(to_rgb(colour), 3))  # noqa: E731
    assert colours.count(rgb(SCANNED)) == 3 and colours.count(rgb(RUNNER_UP)) == 2 and colours.count(rgb(NEXT)) == 1
    assert colours.count(rgb(AXES_COLOUR)) == 3 and labels == ["1", "2", "3", "x", "y", "z"]
    assert "scanned views (3, numbered in scan order)" in texts and "runner-up candidates" in texts and "next-best-view (view 3, behind the object)" in texts


def test_the_views_are_drawn_nearer_so_the_object_fills_the_picture():
    """Views at 0.4 m around a 0.15 m cube would leave the grid a fifth of the width: they are
    drawn at DRAWN_RADIUS grid sides, directions exact, and the legend says how much nearer."""
    from nbvdata.view.render import DRAWN_RADIUS

    views = view_sphere(ViewConfig(count=40))
    fig = draw_state(_grid(), 0.15, views)
    dots, texts = _dots(fig), _legend(fig)
    low, high = fig.axes[0].get_xlim()
    plt.close(fig)
    drawn = dots - 8  # the 16-voxel grid's centre
    assert np.allclose(np.linalg.norm(drawn, axis=1), DRAWN_RADIUS * 16)
    unit = views.positions / np.linalg.norm(views.positions, axis=1, keepdims=True)
    rows = lambda array: np.array(sorted(map(tuple, np.round(array, 6))))  # noqa: E731  (behind, then in front)
    assert np.allclose(rows(drawn / np.linalg.norm(drawn, axis=1, keepdims=True)), rows(unit))
    shown = round(100 * DRAWN_RADIUS * 16 / (0.4 * 16 / 0.15))
    assert (high - low) <= 2 * DRAWN_RADIUS * 16 + 1e-9
    assert f"views drawn at {shown}% of their distance (directions exact)" in texts


def test_unknown_voxels_inside_the_object_are_shown_by_a_cut_away():
    """Without the cut the shell hides every unknown voxel (no face of theirs is drawn); with it the
    cut shows them, and the legend says so. A grid that hides none is drawn whole."""
    shell = _shell()
    filled = shell >= 0.5
    inside = np.zeros_like(filled)
    inside[4:12, 4:12, 4:12] = True
    assert np.array_equal(enclosed(filled), inside)
    colours = np.zeros(shell.shape + (4,))
    colours[shell == 0.5] = UNKNOWN
    _, uncut = exposed_faces(filled, colours)
    assert not (uncut[:, 3] == UNKNOWN[3]).any()  # the whole grid drawn: not one unknown face shows
    fig = draw_state(shell, 0.3)
    drawn, texts = _drawn_colours(fig), _legend(fig)
    plt.close(fig)
    assert CUT_AWAY in texts
    unknown_faces = np.isclose(drawn[:, 3], UNKNOWN[3])
    # the cut's two planes through the unknown block: 8 x 4 voxels each, 4 x 8 along the shared edge
    assert unknown_faces.sum() == 2 * 8 * 4 * 1 and len(drawn) > 0
    solid = np.full((16, 16, 16), 0.4, dtype=np.float32)
    solid[3:13, 3:13, 3:13] = 0.7
    fig = draw_state(solid, 0.3)
    texts, faces = _legend(fig), len(_drawn_colours(fig))
    plt.close(fig)
    assert CUT_AWAY not in texts and faces == 6 * 10 * 10  # nothing hidden but occupied: the cube whole


def test_views_beyond_the_candidates_are_arrows_only():
    """A robot's sensor positions are no candidate views: not counted as such, and a red arrow at
    one of them names no view index."""
    views = view_sphere(ViewConfig(count=40))
    fig = draw_state(_grid(), 0.3, views, highlight=39, others=[37, 38], labels=("next-best-view", "scans (2)"),
                     candidates=37)
    texts = _legend(fig)
    dots = _dots(fig)
    plt.close(fig)
    assert "candidate views (37)" in texts and "next-best-view" in texts and "scans (2)" in texts
    assert len(dots) == 37


@pytest.mark.parametrize("layout", ["hemisphere", "sphere"])
def test_the_png_is_cropped_to_the_drawing(tmp_path, layout):
    out = render_state(_grid(), 0.3, tmp_path / "state.png", view_sphere(ViewConfig(count=500, layout=layout)),
                       highlight=3, title="a title")
    ink = (imread(out)[..., :3] < 250 / 255).any(axis=2)
    blank_rows, blank_cols = (~ink.any(axis=1)).mean(), (~ink.any(axis=0)).mean()
    assert blank_rows < 0.15 and blank_cols < 0.1, (blank_rows, blank_cols)  # was 54 % and 14-33 %
    assert not ink[:4].any() and not ink[-4:].any() and not ink[:, :4].any() and not ink[:, -4:].any()  # a margin


def test_tighten_keeps_the_drawing_whole_and_cuts_the_rest():
    picture = np.full((100, 50, 4), 255, dtype=np.uint8)
    picture[5:8, 10:40, :3] = 0  # a title
    picture[30:35, 20:30, :3] = 0  # the drawing: two parts with a blank gap between them
    picture[50:60, 15:25, :3] = 0
    picture[90:95, 5:45, :3] = 0  # a legend
    tight = tighten(picture, texts=[(5, 7), (90, 94)], margin=3)
    assert tight.shape[:2] == (3 + 3 + 3 + 3 + 30 + 3 + 3 + 5 + 3, 3 + 40 + 3)
    ink = np.flatnonzero((tight[..., :3] < 250).any(axis=2).any(axis=1))
    assert ink.tolist() == [3, 4, 5, *range(12, 17), *range(32, 42), *range(48, 53)]  # the gap 17..31 kept


def _green_pixels(path) -> int:
    """Pixels of the scanned views' green (arrows and numbers) in a PNG, above its legend (the
    lowest 15 % of its rows)."""
    from matplotlib.colors import to_rgb

    from nbvdata.view.render import SCANNED

    pixels = imread(path)[..., :3]
    drawing = pixels[:int(0.85 * len(pixels))]
    return int((np.abs(drawing - np.array(to_rgb(SCANNED))) < 0.12).all(axis=2).sum())


@pytest.mark.parametrize("side, angle", [("behind", 20), ("in front", 20), ("in front", 50)])
def test_the_object_hides_a_view_behind_it_and_none_in_front(side, angle, tmp_path):
    """Issue 58: the draw order of the arrows and the voxels was matplotlib's, one depth per
    collection, so an arrow could be hidden by voxels behind it or drawn over voxels in front of it.
    A solid block filling the grid, one scanned view ``angle`` degrees off the line of sight, its
    arrow and number over the block in the picture: behind the block none of its green shows; in
    front all of it does, as over an empty grid."""
    from nbvdata.core.views import ViewSet, look_at_rotations
    from nbvdata.view.render import VIEW

    elev, azim = np.radians(VIEW["elev"]), np.radians(VIEW["azim"])
    eye = np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])  # to the viewer
    across = np.cross(eye, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    direction = (-1 if side == "behind" else 1) * np.cos(np.radians(angle)) * eye + np.sin(np.radians(angle)) * across
    views = ViewSet(0.4 * direction[None], look_at_rotations(0.4 * direction[None]))
    green = {}
    for name, value in (("solid", 0.7), ("empty", 0.4)):
        grid = np.full((16, 16, 16), value, dtype=np.float32)
        green[name] = _green_pixels(render_state(grid, 0.3, tmp_path / f"{name}.png", views, scanned=[0]))
    assert green["empty"] > 100, green
    if side == "behind":
        assert green["solid"] == 0, green
    else:
        assert green["solid"] >= 0.95 * green["empty"], green


def _red_pixels(path) -> int:
    """Pixels of the next view's red arrow above the legend (as ``_green_pixels``)."""
    pixels = imread(path)[..., :3]
    drawing = pixels[:int(0.85 * len(pixels))]
    return int((np.abs(drawing - np.array([1.0, 0.0, 0.0])) < 0.12).all(axis=2).sum())


def test_the_next_view_is_drawn_over_the_object_even_behind_it(tmp_path):
    """Issue 66: plan --png hid the chosen view's red arrow behind the object. A solid block, the
    view straight behind it: its red shows as over an empty grid, and the legend says where it is."""
    from nbvdata.core.views import ViewSet, look_at_rotations
    from nbvdata.view.render import VIEW

    elev, azim = np.radians(VIEW["elev"]), np.radians(VIEW["azim"])
    eye = np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])
    across = np.cross(eye, [0.0, 0.0, 1.0])
    direction = -np.cos(np.radians(20)) * eye + np.sin(np.radians(20)) * across / np.linalg.norm(across)
    views = ViewSet(0.4 * direction[None], look_at_rotations(0.4 * direction[None]))
    red = {}
    for name, value in (("solid", 0.7), ("empty", 0.4)):
        grid = np.full((16, 16, 16), value, dtype=np.float32)
        red[name] = _red_pixels(render_state(grid, 0.3, tmp_path / f"{name}.png", views, highlight=0))
    assert red["empty"] > 100 and red["solid"] >= 0.95 * red["empty"], red
    fig = draw_state(np.full((16, 16, 16), 0.7, dtype=np.float32), 0.3, views, highlight=0)
    texts = _legend(fig)
    plt.close(fig)
    assert "next-best-view (view 0, behind the object)" in texts


def test_a_long_title_stays_inside_the_picture():
    """Issue 66: nbvdata show clipped a long title (a mesh's path) at both edges: it is wrapped."""
    title = "shard " + "/".join(["a-rather-long-folder-name"] * 8) + "/model.h5, sample 12: 4 scans, NBV view 311"
    fig = draw_state(_grid(), 0.3, view_sphere(ViewConfig(count=40)), title=title)
    fig.canvas.draw()
    (text,) = fig.texts
    box, width = text.get_window_extent(), fig.bbox.width
    plt.close(fig)
    assert box.x0 >= 0 and box.x1 <= width and "".join(text.get_text().split()) == "".join(title.split())


def test_the_scanned_views_are_numbered_in_scan_order():
    """Issue 58: the picture did not say which scan came first. Each scanned view's arrow carries
    its place in the scan order, just beyond its tail; the legend says so, and a highlighted view
    that was scanned names its scan."""
    views = view_sphere(ViewConfig(count=40))
    scanned = [17, 3, 30]
    fig = draw_state(_grid(), 0.3, views, highlight=30, scanned=scanned)
    numbers = {text.get_text(): np.array(text.get_position_3d()) for text in fig.axes[0].texts
               if text.get_text().isdigit()}
    texts = _legend(fig)
    plt.close(fig)
    assert sorted(numbers) == ["1", "2", "3"]
    shrink = 1.2 * 16 / (0.4 * 16 / 0.3)  # the views drawn nearer (DRAWN_RADIUS)
    for number, view in enumerate(scanned, start=1):
        drawn = views.positions[view] * shrink * 16 / 0.3 + 8  # grid units
        beyond = numbers[str(number)] - 8
        assert np.allclose(beyond / np.linalg.norm(beyond), (drawn - 8) / np.linalg.norm(drawn - 8))
        assert np.linalg.norm(beyond) == pytest.approx(1.08 * np.linalg.norm(drawn - 8))
    assert "scanned views (3, numbered in scan order)" in texts and "next-best-view (view 30, scan 3, behind the object)" in texts
