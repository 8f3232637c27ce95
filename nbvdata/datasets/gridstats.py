"""What a dataset's grids look like, step by step: how much of the cube is occupied, unknown,
unknown in the corners, and how far the occupied voxels reach.

Backs ``nbvdata inspect --by-step``, so any set of shards can be compared with the authors'
published grids (``AUTHORS``): a state is summarised by

    occupied        voxels with p > 0.5
    unknown         voxels with p = 0.5 (never observed)
    corner-unknown  share of unknown voxels among the eight CORNER^3 blocks at the cube's corners
    span            extent of the occupied voxels along x, y, z, in voxels (last - first + 1)

and a step by the mean of its states' counts and shares and the median of their spans.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nbvdata.schema.shards import Shard

CORNER = 5
# The authors' 15,166 published grids (nbvdata import-legacy, steps derived from the row order),
# measured with this module: step -> (occupied, unknown, corner-unknown); median span.
AUTHORS = {1: (1251, 10283, 0.12), 2: (2130, 4899, 0.01), 3: (2594, 3746, 0.00), 5: (2667, 3529, 0.00)}
AUTHORS_SPAN = (32, 26, 27)


def grid_statistics(codes: np.ndarray, palette: np.ndarray) -> dict[str, np.ndarray]:
    """Per-state statistics of palette-coded grids.

    codes : (N, n, n, n) integer palette codes; palette : (K,) float32 probabilities
    Returns occupied, unknown (N,) int64, corner_unknown (N,) float64, span (N, 3) int64.
    """
    codes = np.asarray(codes)
    palette = np.asarray(palette, dtype=np.float32)
    occupied = (palette > 0.5)[codes]
    unknown = (palette == 0.5)[codes]
    n = codes.shape[-1]
    ends = (slice(0, CORNER), slice(n - CORNER, n))
    corners = [unknown[:, a, b, c] for a in ends for b in ends for c in ends]
    corner_unknown = sum(c.sum(axis=(1, 2, 3)) for c in corners) / (8 * CORNER ** 3)
    span = np.zeros((len(codes), 3), dtype=np.int64)
    for axis in range(3):
        others = tuple(1 + a for a in range(3) if a != axis)
        seen = occupied.any(axis=others)  # (N, n)
        first = np.argmax(seen, axis=1)
        last = n - 1 - np.argmax(seen[:, ::-1], axis=1)
        span[:, axis] = np.where(seen.any(axis=1), last - first + 1, 0)
    return {"occupied": occupied.sum(axis=(1, 2, 3), dtype=np.int64),
            "unknown": unknown.sum(axis=(1, 2, 3), dtype=np.int64),
            "corner_unknown": corner_unknown.astype(np.float64), "span": span}


@dataclass(frozen=True)
class StepRow:
    """One reconstruction step over a dataset: means of the counts and shares, median span."""

    step: int
    samples: int
    occupied: float
    unknown: float
    corner_unknown: float
    span: tuple[int, int, int]


ALL = 0  # the ``step`` of the row over every state


def by_step(paths: list[Path], chunk: int = 512) -> list[StepRow]:
    """Statistics of every state in the shards at ``paths``, grouped by ``step``, then a row over
    all states (step ``ALL``)."""
    columns: dict[str, list[np.ndarray]] = {"step": [], "occupied": [], "unknown": [], "corner_unknown": [],
                                            "span": []}
    for path in paths:
        with Shard(path) as shard:
            palette, steps = shard.palette, shard["step"]
            for start in range(0, len(shard), chunk):
                stats = grid_statistics(shard.codes(slice(start, start + chunk)), palette)
                for name, values in stats.items():
                    columns[name].append(values)
            columns["step"].append(steps)
    if not columns["step"]:
        return []
    merged = {name: np.concatenate(parts) for name, parts in columns.items()}
    rows = []
    masks = [(step, merged["step"] == step) for step in np.unique(merged["step"]).tolist()]
    for step, mask in masks + [(ALL, np.ones(len(merged["step"]), dtype=bool))]:
        span = np.median(merged["span"][mask], axis=0)
        rows.append(StepRow(step, int(mask.sum()), float(merged["occupied"][mask].mean()),
                            float(merged["unknown"][mask].mean()), float(merged["corner_unknown"][mask].mean()),
                            tuple(int(round(s)) for s in span)))
    return rows


def format_by_step(rows: list[StepRow], authors: bool = True) -> str:
    """A markdown table of ``rows``, with the authors' figures beside each step they report."""
    head = "| step | states | occupied | unknown | corner-unknown | span (median) |"
    if authors:
        head += " authors: occupied / unknown / corner-unknown |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for row in rows:
        line = (f"| {row.step if row.step != ALL else 'all'} | {row.samples:,} | {row.occupied:,.0f} | {row.unknown:,.0f} | "
                f"{row.corner_unknown:.2f} | {' x '.join(map(str, row.span))} |")
        if authors:
            ref = AUTHORS.get(row.step)
            line += (f" {ref[0]:,} / {ref[1]:,} / {ref[2]:.2f} |" if ref else
                     f" span {' x '.join(map(str, AUTHORS_SPAN))} |" if row.step == ALL else " - |")
        lines.append(line)
    return "\n".join(lines)
