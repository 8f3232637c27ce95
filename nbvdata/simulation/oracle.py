"""Ground-truth next-best-view by exact, exhaustive search over every candidate view.

What a noise-free scan from candidate view v covers of the mesh's reference points
(``nbvdata.simulation.coverage``), the set O_v, does not change during a reconstruction. It is computed
once per mesh and kept as a bit matrix, one row of packed bits per view. At a state whose
scans have covered the set C, for every view v:

    new(v)     = |O_v - C|            reference points v would newly cover
    seen(v)    = |O_v & C|            points v would see that are already covered
    gain(v)    = new(v) / |observable|  the increase of the observable coverage if v were scanned
    overlap(v) = seen(v) / |O_v|        (0 for a view that sees nothing)

A view is valid when overlap(v) >= ``min_overlap`` (the authors' 20 % registration overlap).
The next-best-view is the valid view with the largest gain, ties going to the lowest index.
Scoring all views is one AND-NOT, one popcount and one row sum over the bit matrix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def pack_bits(mask: np.ndarray) -> np.ndarray:
    """(..., P) bool -> (..., ceil(P / 64)) uint64, bit p of the row is mask[p]."""
    mask = np.asarray(mask, dtype=bool)
    words = -(-mask.shape[-1] // 64)
    padded = np.zeros(mask.shape[:-1] + (words * 64,), dtype=bool)
    padded[..., :mask.shape[-1]] = mask
    return np.packbits(padded, axis=-1, bitorder="little").view(np.uint64)


def unpack_bits(bits: np.ndarray, count: int) -> np.ndarray:
    """Inverse of ``pack_bits``: (..., W) uint64 -> (..., count) bool."""
    return np.unpackbits(bits.view(np.uint8), axis=-1, count=count, bitorder="little").astype(bool)


def popcount(bits: np.ndarray) -> int:
    """Number of set bits in a packed mask."""
    return int(np.bitwise_count(bits).sum(dtype=np.int64))


def overlap(seen: np.ndarray, covered: np.ndarray) -> float:
    """|seen & covered| / |seen| of two (W,) packed point masks (0 when ``seen`` is empty): the
    overlap of what a scan actually covered, ``seen``, with what was covered before it; for a
    candidate view's noise-free scan (seen = O_v) it is that view's overlap(v)."""
    count = popcount(seen)
    return popcount(seen & covered) / count if count else 0.0


@dataclass(frozen=True)
class Scores:
    """Every candidate view scored at one state.

    new, seen : (V,) int32 reference points each view would newly cover / cover again
    gains, overlaps : (V,) float64 as defined in the module docstring
    """

    new: np.ndarray
    seen: np.ndarray
    gains: np.ndarray
    overlaps: np.ndarray

    def best(self, min_overlap: float, min_gain: float = 0.0) -> int | None:
        """Index of the next-best-view, or None when no valid view adds at least ``min_gain``
        (and at least one new point)."""
        valid = (self.overlaps >= min_overlap) & (self.new > 0) & (self.gains >= min_gain)
        if not valid.any():
            return None
        return int(np.argmax(np.where(valid, self.gains, -1.0)))  # argmax: first of the ties


class ViewOracle:
    """The per-mesh bit matrix of what each candidate view observes, and the scoring.

    visible : (V, W) uint64 packed rows, bit p of row v set when view v covers point p
    view_counts : (V,) int32 points each view covers, |O_v|
    observable : (W,) uint64 packed union of all rows
    """

    def __init__(self, visible: np.ndarray):
        """``visible``: (V, P) bool, what a noise-free scan from each view covers."""
        visible = np.asarray(visible, dtype=bool)
        self.points = visible.shape[1]
        self.visible = pack_bits(visible)
        self.view_counts = visible.sum(axis=1, dtype=np.int32)
        self.observable = np.bitwise_or.reduce(self.visible, axis=0)
        self.observable_count = popcount(self.observable)
        self._and = np.empty_like(self.visible)
        self._counts = np.empty(self.visible.shape, dtype=np.uint8)
        self._point_views: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.visible)

    @property
    def point_views(self) -> np.ndarray:
        """(P, ceil(V / 64)) uint64: the transposed bit matrix, bit v of row p set when view v
        covers point p (each point's covering set, for ``nbvdata.simulation.setcover``); made on first use."""
        if self._point_views is None:
            self._point_views = pack_bits(unpack_bits(self.visible, self.points).T)
        return self._point_views

    def score(self, covered: np.ndarray) -> Scores:
        """Score every view at the state whose covered points are ``covered`` ((W,) packed)."""
        np.bitwise_and(self.visible, ~covered, out=self._and)
        np.bitwise_count(self._and, out=self._counts)
        new = self._counts.sum(axis=1, dtype=np.int32)
        seen = self.view_counts - new
        gains = new / max(self.observable_count, 1)
        overlaps = np.divide(seen, self.view_counts, out=np.zeros(len(new)), where=self.view_counts > 0)
        return Scores(new, seen, gains, overlaps)

    def observable_coverage(self, covered: np.ndarray) -> float:
        """Fraction of the observable reference points in ``covered`` ((W,) packed)."""
        return popcount(covered & self.observable) / max(self.observable_count, 1)
