"""Headless pictures of a reconstruction state, like the paper's Fig. 1.

Occupied voxels are blue, unknown voxels yellow, candidate views grey dots, and highlighted
views arrows pointing at the object centre (red for the chosen one, orange for others).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from nbvdata.views import ViewSet  # noqa: E402


def render_state(
    probabilities: np.ndarray,
    extent: float,
    out: str | Path,
    views: ViewSet | None = None,
    highlight: int | None = None,
    others: Sequence[int] = (),
    title: str = "",
) -> Path:
    """Write a PNG of a grid state and the view sphere; returns the path written.

    probabilities : (n, n, n) float32 in the authors' encoding (0.5 = unknown)
    extent : side of the grid cube in metres (to place the views in grid units)
    highlight : index into ``views`` of the view drawn as a red arrow
    others : indices drawn as orange arrows (e.g. the runner-up candidates)
    """
    probabilities = np.asarray(probabilities)
    n = probabilities.shape[0]
    occupied = probabilities > 0.5
    unknown = probabilities == 0.5
    colors = np.zeros(probabilities.shape + (4,))
    colors[unknown] = (1.0, 0.85, 0.1, 0.25)
    colors[occupied] = (0.15, 0.35, 0.85, 1.0)

    fig = plt.figure(figsize=(7, 7), dpi=110)
    ax = fig.add_subplot(projection="3d")
    quads, face_colors = exposed_faces(occupied | unknown, colors)
    ax.add_collection3d(Poly3DCollection(quads, facecolors=face_colors, edgecolors=(0, 0, 0, 0.08),
                                         linewidths=0.2))

    scale = n / extent  # metres -> grid units; the grid's centre is at n / 2
    def to_grid(points: np.ndarray) -> np.ndarray:
        return np.asarray(points) * scale + n / 2

    if views is not None:
        positions = to_grid(views.positions)
        ax.scatter(*positions.T, s=3, c="0.55", depthshade=False)
        for index, color in [(i, "orange") for i in others] + ([(highlight, "red")] if highlight is not None else []):
            start = positions[index]
            arrow = (to_grid(np.zeros(3)) - start) * 0.35
            ax.quiver(*start, *arrow, color=color, linewidth=2.5, arrow_length_ratio=0.3)
        reach = np.abs(positions - n / 2).max()
        low, high = n / 2 - reach, n / 2 + reach
    else:
        low, high = 0, n
    ax.set_xlim(low, high)
    ax.set_ylim(low, high)
    ax.set_zlim(low if views is None or views.positions[:, 2].min() < 0 else 0, high)
    ax.set_box_aspect((1, 1, 1) if views is None or views.positions[:, 2].min() < 0 else (2, 2, 1))
    ax.set_axis_off()
    counts = f"occupied {occupied.sum()}, unknown {unknown.sum()}, free {(probabilities < 0.5).sum()}"
    ax.set_title(f"{title}\n{counts}" if title else counts, fontsize=10)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, bbox_inches="tight")
    plt.close(fig)
    return out


# Unit square corners (u, v) of a voxel face, in drawing order.
_SQUARE = np.array([(0, 0), (1, 0), (1, 1), (0, 1)])
# Brightness of faces by (axis, side): a fixed light from above and in front, as a shading cue.
_SHADE = {(0, 0): 0.70, (0, 1): 0.85, (1, 0): 0.80, (1, 1): 0.65, (2, 0): 0.55, (2, 1): 1.0}


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
