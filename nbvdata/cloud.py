"""Partial point clouds of a reconstruction: every scanned point so far, reduced to a fixed size.

PC-NBV's networks read the *accumulated partial cloud*: all the points the scans have returned.
``ScannedCloud`` collects them scan by scan (a scan's hits in ray order, scans in the order they
were taken) and ``reduce_cloud`` gives a fixed-size cloud of N of them:

- more than N points: N chosen by farthest-point sampling (FPS) - the first point of the cloud,
  then again and again the point farthest from those chosen so far (the lowest index among
  equally far ones) - an exact, deterministic rule;
- N or fewer: all of them in their order, repeated from the first until there are N.

The generator (``nbvdata.episode``), the closed-loop planners (``nbvtrain.planners``) and
``nbvtrain plan`` all build their clouds here, so a network sees the same clouds in closed loop
as in its training data.

``farthest_points`` is the exact FPS of ``farthest_points_reference`` (the plain O(N M) loop,
kept for the tests), only faster: the points are bucketed into cells, and a new sample changes
only the distances of points nearer to it than the largest distance left, so only the cells
within that reach are visited; a tournament tree over the cells' largest distances gives the
next sample. Distances are squared, in float64, from the float32 points, with a fixed order of
operations and no fused multiply-add (numba without fastmath): the same indices on every CPU.
A cell is skipped only when a lower bound of its points' distances, computed with the same
operations on its points' own bounding box, is not below the largest distance left; rounding is
monotone, so the bound never exceeds a point's computed distance and a skipped point's distance
could not have changed. The two versions give the same indices (tested).
"""

from __future__ import annotations

import numba
import numpy as np

# Points per leaf of the search tree.
_LEAF = 8


class ScannedCloud:
    """The hit points of the scans of one reconstruction, in scan order.

    ``add((H, 3) float32)`` after each scan; ``points()`` is all of them, (M, 3) float32.
    """

    def __init__(self):
        self._scans: list[np.ndarray] = []

    def add(self, hit_points: np.ndarray) -> None:
        self._scans.append(np.ascontiguousarray(hit_points, dtype=np.float32).reshape(-1, 3))

    def __len__(self) -> int:
        return sum(len(scan) for scan in self._scans)

    def points(self) -> np.ndarray:
        """(M, 3) float32 every scanned point, oldest scan first."""
        if not self._scans:
            return np.zeros((0, 3), dtype=np.float32)
        return np.concatenate(self._scans) if len(self._scans) > 1 else self._scans[0]

    def reduce(self, count: int) -> tuple[np.ndarray, int]:
        """``reduce_cloud`` of every scanned point."""
        return reduce_cloud(self.points(), count)


def reduce_cloud(points: np.ndarray, count: int) -> tuple[np.ndarray, int]:
    """((count, 3) float32 cloud, M): ``points`` (M, 3) reduced to exactly ``count`` by
    farthest-point sampling from the first point when M > count, else all of them repeated
    cyclically to ``count``; M is the number of points given. With no points at all: zeros."""
    points = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 3)
    if count < 1:
        raise ValueError(f"count={count}: a reduced cloud holds at least 1 point")
    total = len(points)
    if total == 0:
        return np.zeros((count, 3), dtype=np.float32), 0
    if total <= count:
        return points[np.arange(count) % total], total
    return points[farthest_points(points, count)], total


def farthest_points(points: np.ndarray, count: int) -> np.ndarray:
    """(count,) int64 indices into ``points`` (M, 3) float32, M >= count >= 1, in the order
    farthest-point sampling picks them, starting from index 0 (see the module docstring)."""
    points = np.ascontiguousarray(points, dtype=np.float32)
    if not 1 <= count <= len(points):
        raise ValueError(f"count={count}: farthest-point sampling picks 1..{len(points)} of these points")
    return _farthest_points_tree(points.astype(np.float64), count)


@numba.njit(cache=True)
def _split(placed, order, first, stop, axis, rank):
    """Reorder rows ``first:stop`` of ``placed`` (M, 3) and ``order`` (M,) alike so that row
    ``rank`` holds the point that would be there sorted by coordinate ``axis``, none after it
    lower, none before it higher (quickselect with median-of-three pivots: deterministic)."""
    while stop - first > 2:
        middle = (first + stop - 1) // 2
        a, b, c = placed[first, axis], placed[middle, axis], placed[stop - 1, axis]
        pivot = max(min(a, b), min(max(a, b), c))
        i, j = first, stop - 1
        while True:  # Hoare: [first, i) <= pivot <= (j, stop)
            while placed[i, axis] < pivot:
                i += 1
            while placed[j, axis] > pivot:
                j -= 1
            if i >= j:
                break
            for a in range(3):
                placed[i, a], placed[j, a] = placed[j, a], placed[i, a]
            order[i], order[j] = order[j], order[i]
            i += 1
            j -= 1
        if rank <= j:
            stop = j + 1
        else:
            first = j + 1
    if stop - first == 2 and placed[first, axis] > placed[first + 1, axis]:
        for a in range(3):
            placed[first, a], placed[first + 1, a] = placed[first + 1, a], placed[first, a]
        order[first], order[first + 1] = order[first + 1], order[first]


@numba.njit(cache=True)
def _farthest_points_tree(points, count):
    """FPS over ``points`` (M, 3) float64 from index 0, ties going to the lowest index: the
    rule of ``farthest_points_reference``, with a k-d tree of 2^depth leaves of at most
    ``_LEAF`` points (halved at the median of the widest side). Every node holds its points'
    bounding box and their farthest point from the samples so far (value, index); a sample
    visits only the nodes that reach nearer to it than the largest distance left."""
    total = points.shape[0]
    leaves = 1
    while leaves * _LEAF < total:
        leaves *= 2
    first = np.zeros(2 * leaves, dtype=np.int64)
    stop = np.zeros(2 * leaves, dtype=np.int64)
    low = np.full((2 * leaves, 3), np.inf)
    high = np.full((2 * leaves, 3), -np.inf)
    order = np.arange(total)
    placed = points.copy()  # the points in leaf order, contiguous
    stop[1] = total
    for node in range(1, 2 * leaves):
        for k in range(first[node], stop[node]):
            for a in range(3):
                low[node, a] = min(low[node, a], placed[k, a])
                high[node, a] = max(high[node, a], placed[k, a])
        if node >= leaves:
            continue
        axis = 0
        for a in (1, 2):
            if high[node, a] - low[node, a] > high[node, axis] - low[node, axis]:
                axis = a
        middle = first[node] + (stop[node] - first[node]) // 2
        _split(placed, order, first[node], stop[node], axis, middle)
        first[2 * node], stop[2 * node] = first[node], middle
        first[2 * node + 1], stop[2 * node + 1] = middle, stop[node]
    value = np.full(2 * leaves, -np.inf)
    index = np.full(2 * leaves, np.iinfo(np.int64).max)  # the node's farthest point (ties: lowest index)
    nearest = np.full(total, np.inf)  # squared distance to the nearest sample so far, leaf order
    chosen = np.empty(count, dtype=np.int64)
    stack = np.empty(2 * leaves, dtype=np.int64)
    visited = np.empty(2 * leaves, dtype=np.int64)
    sample = 0
    for s in range(count):
        chosen[s] = sample
        x, y, z = points[sample, 0], points[sample, 1], points[sample, 2]
        reach = np.inf if s == 0 else value[1]  # the largest distance left: only nearer points change
        top, seen = 1, 0
        stack[0] = 1
        while top > 0:
            top -= 1
            node = stack[top]
            gx = max(max(low[node, 0] - x, 0.0), x - high[node, 0])
            gy = max(max(low[node, 1] - y, 0.0), y - high[node, 1])
            gz = max(max(low[node, 2] - z, 0.0), z - high[node, 2])
            if not gx * gx + gy * gy + gz * gz < reach:
                continue  # no point of the node is nearer than the largest distance left
            if node >= leaves:
                best_value, best_index = -np.inf, np.iinfo(np.int64).max
                for k in range(first[node], stop[node]):
                    dx = placed[k, 0] - x
                    dy = placed[k, 1] - y
                    dz = placed[k, 2] - z
                    d = dx * dx + dy * dy + dz * dz
                    if d < nearest[k]:
                        nearest[k] = d
                    if nearest[k] > best_value or (nearest[k] == best_value and order[k] < best_index):
                        best_value, best_index = nearest[k], order[k]
                value[node], index[node] = best_value, best_index
            else:
                visited[seen] = node
                seen += 1
                stack[top] = 2 * node
                stack[top + 1] = 2 * node + 1
                top += 2
        for v in range(seen - 1, -1, -1):  # children before parents
            node = visited[v]
            left, right = 2 * node, 2 * node + 1
            if value[right] > value[left] or (value[right] == value[left] and index[right] < index[left]):
                left = right
            value[node], index[node] = value[left], index[left]
        sample = index[1]
    return chosen


@numba.njit(cache=True)
def farthest_points_reference(points, count):
    """The plain FPS loop from index 0 (O(count * M)): what ``farthest_points`` must equal.
    ``points`` (M, 3) float32; returns (count,) int64 indices."""
    total = points.shape[0]
    nearest = np.full(total, np.inf)
    chosen = np.empty(count, dtype=np.int64)
    sample = 0
    for s in range(count):
        chosen[s] = sample
        x = np.float64(points[sample, 0])
        y = np.float64(points[sample, 1])
        z = np.float64(points[sample, 2])
        best_value, best_index = -np.inf, 0
        for i in range(total):
            dx = np.float64(points[i, 0]) - x
            dy = np.float64(points[i, 1]) - y
            dz = np.float64(points[i, 2]) - z
            d = dx * dx + dy * dy + dz * dz
            if d < nearest[i]:
                nearest[i] = d
            if nearest[i] > best_value:
                best_value, best_index = nearest[i], i
        sample = best_index
    return chosen
