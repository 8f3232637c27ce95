"""Headless pictures of a reconstruction state, like the paper's Fig. 1.

Occupied voxels are blue, unknown voxels yellow, a partial point cloud (if given) black dots,
candidate views grey dots. Views are arrows pointing at the object centre, one colour one
meaning in every picture (``show``, ``demo``, ``plan --png``): red the next view (the NBV, a
planner's answer, a highlighted view), orange the runner-up candidates, green the views scanned
so far. A legend says so, with the voxel counts. An x, y, z triad at the grid's corner shows the
orientation (z up). The views are drawn nearer than they are - their directions exact, their
distances shrunk alike (the legend says by how much) - so the object fills much of the picture
rather than a fifth of it. Unknown voxels enclosed by others (the inside of an object, which no
scan reaches) would show no face: then the quarter of the grid facing the viewer is cut away,
so that the cut shows them, and the legend says so. The scanned views' arrows are numbered in
scan order. What lies behind the grid's centre, as seen from the picture's viewpoint (views,
their arrows and numbers), is drawn before the voxels and what lies in front after them, so the
voxels hide a view behind the object and never one in front: exact for views outside the grid's
circumscribed sphere (all of them, drawn nearer as they are). The next view's red arrow is drawn
over everything, wherever it lies (the legend says when it lies behind the object). A long title
is wrapped to the figure's width. The PNG is cropped to what is drawn.
"""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import patheffects  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from nbvdata.core.views import ViewSet  # noqa: E402

OCCUPIED = (0.15, 0.35, 0.85, 1.0)
UNKNOWN = (1.0, 0.85, 0.1, 0.25)
NEXT, RUNNER_UP, SCANNED = "red", "orange", (0.1, 0.55, 0.2)  # the arrows' colours, the same in every picture
AXES_COLOUR = "0.25"
DRAWN_RADIUS = 1.2  # the farthest view is drawn this many grid sides from the centre
MARGIN_PX = 8  # blank pixels kept around the drawing, the title and the legend
VIEW = {"elev": 30, "azim": -60}  # the 3D axes' viewpoint (matplotlib's default): from +x, -y and above
CUT_AWAY = "front quarter cut away to show the inside"
BEHIND, VOXELS, IN_FRONT, ON_TOP = 1, 2, 3, 4  # the draw order (zorder): behind the grid's centre, the voxels, ...
TITLE_CHARACTERS = 90  # a title's line at most: what the 7-inch figure holds at 10 points
HALO = [patheffects.withStroke(linewidth=3, foreground="white")]  # the scan numbers readable over the voxels


def render_state(probabilities: np.ndarray, extent: float, out: str | Path, views: ViewSet | None = None,
                 **drawing) -> Path:
    """Write a PNG of a grid state and the view sphere, cropped to the drawing; returns the path.

    ``drawing``: the keyword arguments of ``draw_state`` (highlight, others, title, labels, ...).
    """
    return save_cropped(draw_state(probabilities, extent, views, **drawing), out)


def save_cropped(fig: Figure, out: str | Path) -> Path:
    """Write ``fig`` (a ``draw_state`` figure) as a PNG cropped to its drawing, title and legend,
    and close it; returns the path."""
    fig.canvas.draw()
    pixels = np.asarray(fig.canvas.buffer_rgba())
    height = pixels.shape[0]
    texts = [artist.get_window_extent() for artist in fig.texts + fig.legends]
    plt.close(fig)
    pixels = tighten(pixels, [(height - int(np.ceil(box.y1)), height - int(box.y0)) for box in texts])
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    plt.imsave(out, pixels, format="png")
    return out


def tighten(pixels: np.ndarray, texts: Sequence[tuple[int, int]] = (), margin: int = MARGIN_PX) -> np.ndarray:
    """An (H, W, 4) uint8 picture cut to its drawing and its texts, each with ``margin`` blank
    pixels around it: the blank border and the blank rows between them go.

    texts : (first, last) rows of each text block (title, legend); the drawing is all other ink,
    kept whole from its first row to its last.

    A 3D axes reserves room for the corners of its rotated bounding box, so a drawing of the view
    sphere left about a third of the figure blank; cropping the pixels removes it whatever the view.
    """
    ink = (pixels[..., :3] < 250).any(axis=2)
    cols = np.flatnonzero(ink.any(axis=0))
    if not len(cols):
        return pixels
    in_text = np.zeros(len(ink), dtype=bool)
    for first, last in texts:
        in_text[max(first, 0):last + 1] = True
    drawing = np.flatnonzero(ink.any(axis=1) & ~in_text)
    blocks = list(texts) + ([(drawing[0], drawing[-1])] if len(drawing) else [])
    keep = np.zeros(len(ink), dtype=bool)
    for first, last in blocks:
        keep[max(first - margin, 0):last + margin + 1] = True
    return pixels[keep][:, max(cols[0] - margin, 0):cols[-1] + margin + 1]


def draw_state(
    probabilities: np.ndarray,
    extent: float,
    views: ViewSet | None = None,
    highlight: int | None = None,
    others: Sequence[int] = (),
    title: str = "",
    labels: tuple[str, str] = ("next-best-view", "runner-up candidates"),
    views_label: str = "candidate views",
    candidates: int | None = None,
    points: np.ndarray | None = None,
    scanned: Sequence[int] = (),
    scanned_label: str = "scanned views",
) -> Figure:
    """The figure of a grid state and the view sphere, with a legend (the caller closes it).

    probabilities : (n, n, n) float32 in the authors' encoding (0.5 = unknown)
    extent : side of the grid cube in metres (to place the views in grid units)
    highlight : index into ``views`` of the next view, drawn as a red arrow
    others : indices drawn as orange arrows: the runner-up candidates
    labels : what the red and the orange arrows are, for the legend
    views_label : what the grey dots are, for the legend
    candidates : the first ``candidates`` views are the candidate views, drawn as grey dots; the
        others (e.g. a robot's sensor positions) only as arrows (None: all views are candidates).
        The red arrow's legend names its view index only when it is a candidate.
    points : (P, 3) a partial point cloud in metres, object frame, drawn as black dots
    scanned : indices of the views scanned so far, in scan order, drawn as green arrows numbered
        1, 2, ... in that order (``scanned_label`` and their count in the legend)
    """
    probabilities = np.asarray(probabilities)
    n = probabilities.shape[0]
    occupied = probabilities > 0.5
    unknown = probabilities == 0.5
    colors = np.zeros(probabilities.shape + (4,))
    colors[unknown] = UNKNOWN
    colors[occupied] = OCCUPIED

    fig = plt.figure(figsize=(7, 7), dpi=110)
    ax = fig.add_axes((0, 0, 1, 1), projection="3d")
    ax.view_init(**VIEW)
    ax.computed_zorder = False  # drawn in the order BEHIND, VOXELS, IN_FRONT, ON_TOP (module docstring)
    filled = occupied | unknown
    cut = bool((unknown & enclosed(filled)).any())
    if cut:
        filled = filled.copy()
        filled[n - n // 2:, :n // 2] = False  # the quarter facing VIEW's viewpoint
    quads, face_colors = exposed_faces(filled, colors)
    ax.add_collection3d(Poly3DCollection(quads, facecolors=face_colors, edgecolors=(0, 0, 0, 0.08),
                                         linewidths=0.2, zorder=VOXELS))

    scale = n / extent  # metres -> grid units; the grid's centre is at n / 2
    def to_grid(points: np.ndarray) -> np.ndarray:
        return np.asarray(points) * scale + n / 2

    shrink = 1.0  # the views drawn nearer, their directions exact (module docstring)
    if views is not None and len(views.positions):
        farthest = float(np.linalg.norm(views.positions, axis=1).max()) * scale
        shrink = min(1.0, DRAWN_RADIUS * n / farthest) if farthest > 0 else 1.0

    legend = [Patch(facecolor=OCCUPIED, edgecolor="0.3", label=f"occupied ({occupied.sum()} voxels)"),
              Patch(facecolor=UNKNOWN[:3] + (0.5,), edgecolor="0.3", label=f"unknown ({unknown.sum()})"),
              Patch(facecolor="white", edgecolor="0.6", label=f"free ({(probabilities < 0.5).sum()}, not drawn)")]
    if cut:
        legend.append(Patch(facecolor="none", edgecolor="none", label=CUT_AWAY))
    if points is not None and len(points):  # the cloud over the voxels, not hidden among them
        ax.scatter(*to_grid(points).T, s=2, c="black", depthshade=False, zorder=ON_TOP)
        legend.append(Line2D([], [], linestyle="", marker="o", markersize=2, color="black",
                             label=f"partial cloud ({len(points)} points)"))
    upper = views is not None and views.positions[:, 2].min() >= 0  # a dome: draw its half of the cube
    if views is not None:
        positions = to_grid(views.positions * shrink)
        layer = np.where((positions - n / 2) @ toward_viewer() < 0, BEHIND, IN_FRONT)  # each view's
        candidates = len(positions) if candidates is None else candidates
        for side in (BEHIND, IN_FRONT):
            ax.scatter(*positions[:candidates][layer[:candidates] == side].T, s=3, c="0.55", depthshade=False,
                       zorder=side)
        legend.append(Line2D([], [], linestyle="", marker="o", markersize=4, color="0.55",
                             label=f"{views_label} ({candidates})"))
        arrows = ([(i, SCANNED) for i in scanned] + [(i, RUNNER_UP) for i in others]
                  + ([(highlight, NEXT)] if highlight is not None else []))
        for index, color in arrows:
            start = positions[index]
            arrow = (to_grid(np.zeros(3)) - start) * 0.35
            ax.quiver(*start, *arrow, color=color, linewidth=2.5, arrow_length_ratio=0.3,
                      zorder=ON_TOP if color == NEXT else layer[index])  # the next view is never hidden
        for number, index in enumerate(scanned, start=1):  # scan order, just beyond the arrow's tail
            ax.text(*(positions[index] + 0.08 * (positions[index] - n / 2)), str(number), color=SCANNED,
                    fontsize=9, fontweight="bold", ha="center", va="center", zorder=layer[index],
                    path_effects=HALO)
        if highlight is not None:
            which = [f"view {highlight}"] if highlight < candidates else []
            which += [f"scan {list(scanned).index(highlight) + 1}"] if highlight in scanned else []
            which += ["behind the object"] if layer[highlight] == BEHIND else []
            legend.append(Line2D([], [], color=NEXT, linewidth=2.5,
                                 label=labels[0] + (f" ({', '.join(which)})" if which else "")))
        if len(others):
            legend.append(Line2D([], [], color=RUNNER_UP, linewidth=2.5, label=labels[1]))
        if len(scanned):
            legend.append(Line2D([], [], color=SCANNED, linewidth=2.5,
                                 label=f"{scanned_label} ({len(scanned)}, numbered in scan order)"))
        if shrink < 1.0:
            legend.append(Patch(facecolor="none", edgecolor="none",
                                label=f"views drawn at {100 * shrink:.0f}% of their distance (directions exact)"))
        reach = np.abs(positions - n / 2).max()
        low, high = n / 2 - reach, n / 2 + reach
    else:
        low, high = 0, n
    _orientation(ax, n)
    bottom = 0 if upper else low  # a dome of views: down to the grid's floor
    ax.set_xlim(low, high)
    ax.set_ylim(low, high)
    ax.set_zlim(bottom, high)
    # equal scale on every axis; zoom: the 3D axes leaves room for its box's corners, which the
    # sphere of views does not reach (tighten crops what stays blank)
    ax.set_box_aspect((high - low, high - low, high - bottom), zoom=1.3 if views is not None else 1.0)
    ax.set_axis_off()
    fig.legend(handles=legend, loc="lower center", ncol=3 if len(legend) <= 6 else 2, fontsize=8, frameon=False)
    if title:  # wrapped to the figure's width: a long one (a mesh's path) would run off both edges
        fig.text(0.5, 0.99, textwrap.fill(title, TITLE_CHARACTERS, break_on_hyphens=False), ha="center", va="top", fontsize=10)
    return fig


def toward_viewer() -> np.ndarray:
    """(3,) unit vector from the grid's centre towards the picture's viewpoint (``VIEW``)."""
    elev, azim = np.radians(VIEW["elev"]), np.radians(VIEW["azim"])
    return np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])


def _orientation(ax, n: int) -> None:
    """An x, y, z triad just outside the grid's lowest corner (so the grid hides none of it), a
    quarter of a side long, labelled."""
    length, origin = n / 4, np.array([-n / 8, -n / 8, 0.0])
    for axis, name in enumerate("xyz"):
        tip = np.zeros(3)
        tip[axis] = length
        ax.quiver(*origin, *tip, color=AXES_COLOUR, linewidth=1.2, arrow_length_ratio=0.25, zorder=ON_TOP)
        ax.text(*(origin + tip * 1.3), name, color=AXES_COLOUR, fontsize=9, ha="center", va="center", zorder=ON_TOP)


# Unit square corners (u, v) of a voxel face, in drawing order.
_SQUARE = np.array([(0, 0), (1, 0), (1, 1), (0, 1)])
# Brightness of faces by (axis, side): a fixed light from above and in front, as a shading cue.
_SHADE = {(0, 0): 0.70, (0, 1): 0.85, (1, 0): 0.80, (1, 1): 0.65, (2, 0): 0.55, (2, 1): 1.0}


def enclosed(filled: np.ndarray) -> np.ndarray:
    """(n, n, n) bool: the filled voxels whose six neighbours are all filled (no face of theirs is
    drawn); ``filled`` (n, n, n) bool, the grid's outside counts as empty."""
    padded = np.pad(filled, 1)
    inner = filled.copy()
    for axis in range(3):
        for shift in (-1, 1):
            inner &= np.roll(padded, shift, axis=axis)[1:-1, 1:-1, 1:-1]
    return inner


def exposed_faces(filled: np.ndarray, colors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The voxel faces not hidden by a filled neighbour, as one batch of quads.

    filled : (n, n, n) bool; colors : (n, n, n, 4) RGBA per voxel
    Returns quads (F, 4, 3) in voxel units and their shaded colours (F, 4). The same faces as
    ``Axes3D.voxels`` draws, but as one collection, which renders a 32^3 grid in about a second
    instead of tens.
    """
    quads, face_colors = [], []
    padded = np.pad(filled, 1)
    n = filled.shape[0]
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        for side in (0, 1):
            neighbour = np.take(padded, np.arange(n) + 2 * side, axis=axis)[tuple(
                slice(1, -1) if a != axis else slice(None) for a in range(3))]
            cells = np.argwhere(filled & ~neighbour)  # (F, 3)
            corners = np.repeat(cells[:, None, :], 4, axis=1).astype(np.float64)
            corners[:, :, axis] += side
            corners[:, :, u] += _SQUARE[:, 0]
            corners[:, :, v] += _SQUARE[:, 1]
            quads.append(corners)
            shaded = colors[tuple(cells.T)].astype(np.float64)
            shaded[:, :3] *= _SHADE[axis, side]
            face_colors.append(shaded)
    return np.concatenate(quads), np.concatenate(face_colors)
