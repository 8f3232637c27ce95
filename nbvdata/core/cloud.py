"""Partial point clouds of a reconstruction: every scanned point so far, reduced to a fixed size.

PC-NBV's networks read the *accumulated partial cloud*: all the points the scans have returned.
``ScannedCloud`` collects them scan by scan (a scan's hits in ray order, scans in the order they
were taken) and ``reduce_cloud`` gives a fixed-size cloud of N of them:

- more than N points: N chosen by farthest-point sampling (FPS) - the first point of the cloud,
  then again and again the point farthest from those chosen so far (the lowest index among
  equally far ones) - an exact, deterministic rule;
- N or fewer: all of them in their order, repeated from the first until there are N.

The generator (``nbvdata.simulation.episode``), the closed-loop planners (``nbvtrain.planners``) and
``nbvtrain plan`` all build their clouds here, so a network sees the same clouds in closed loop
as in its training data.

``farthest_points`` gives exactly the indices of ``farthest_points_reference`` (the plain
O(N M) loop, kept for the tests), only faster: the points go into a k-d tree whose every node
holds its points' bounding box and their largest distance to the samples so far, and a new
sample visits only the nodes whose box comes nearer to it than that largest distance - the
others' distances cannot change; the root gives the next sample. Distances are squared, in
float64, from the float32 points, with a fixed order of operations and no fused multiply-add
(numba without fastmath): the same indices on every CPU. A node's bound is computed with the
same operations from its box, and rounding is monotone, so it never exceeds a point's computed
distance: skipping a node never skips a change. The tree's shape changes nothing but the speed
(tested against the plain loop, index for index). A tree per scan, kept across a run's states,
was measured too: no faster (the scans overlap, so every sample visited every scan's tree),
and the tree of a whole cloud builds in a small part of the sampling's time.
"""

from __future__ import annotations

import numba
import numpy as np

# Points per leaf of a tree at most.
_LEAF = 8


class ScannedCloud:
    """The hit points of the scans of one reconstruction, in scan order.

    ``add((H, 3) float32)`` after each scan; ``points()`` is all of them, (M, 3) float32;
    ``reduce(N)`` the cloud of N of them (``reduce_cloud``).
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
    return _farthest_points_tree(*_build_tree(points.astype(np.float64)), count)


@numba.njit(cache=True)
def _build_tree(points):
    """A k-d tree of ``points`` (n, 3) float64, nodes split at the middle of their box's widest
    side down to leaves of at most ``_LEAF`` points (or of one repeated point): placed (n, 3) the
    points in leaf order, order (n,) their index in ``points``, and per node (node 0 the root)
    first, stop (its points are placed[first:stop]), child (its first child, the second follows;
    -1 for a leaf) and low, high (K, 3) its bounding box."""
    total = points.shape[0]
    capacity = 2 * total + 1
    first = np.zeros(capacity, dtype=np.int64)
    stop = np.zeros(capacity, dtype=np.int64)
    child = np.full(capacity, -1, dtype=np.int64)
    low = np.empty((capacity, 3))
    high = np.empty((capacity, 3))
    order = np.arange(total)
    placed = points.copy()
    stop[0] = total
    for a in range(3):
        low[0, a] = placed[:, a].min()
        high[0, a] = placed[:, a].max()
    nodes = 1
    pending = np.empty(capacity, dtype=np.int64)
    pending[0], waiting = 0, 1
    while waiting > 0:
        waiting -= 1
        node = pending[waiting]
        if stop[node] - first[node] <= _LEAF:
            continue
        axis = 0
        for a in (1, 2):
            if high[node, a] - low[node, a] > high[node, axis] - low[node, axis]:
                axis = a
        middle = low[node, axis] + (high[node, axis] - low[node, axis]) / 2
        left, right = nodes, nodes + 1
        for a in range(3):
            low[left, a], high[left, a], low[right, a], high[right, a] = np.inf, -np.inf, np.inf, -np.inf
        i, j = first[node], stop[node] - 1
        while i <= j:  # the points below the middle to the front, the others to the back
            if placed[i, axis] < middle:
                side, k = left, i
                i += 1
            else:
                for a in range(3):
                    placed[i, a], placed[j, a] = placed[j, a], placed[i, a]
                order[i], order[j] = order[j], order[i]
                side, k = right, j
                j -= 1
            for a in range(3):
                low[side, a] = min(low[side, a], placed[k, a])
                high[side, a] = max(high[side, a], placed[k, a])
        if i == first[node] or i == stop[node]:
            continue  # no two distinct coordinates to split at: a leaf, however many points
        first[left], stop[left], first[right], stop[right] = first[node], i, i, stop[node]
        child[node] = left
        nodes += 2
        pending[waiting], pending[waiting + 1] = left, right
        waiting += 2
    return (placed, order, first[:nodes].copy(), stop[:nodes].copy(), child[:nodes].copy(), low[:nodes].copy(),
            high[:nodes].copy())


@numba.njit(cache=True)
def _farthest_points_tree(placed, order, first, stop, child, low, high, count):
    """FPS from the point of index 0, ties going to the lowest index (the rule of
    ``farthest_points_reference``), over the tree of ``_build_tree``. Every node keeps its points'
    farthest point from the samples so far (value, index); a sample visits only the nodes whose box
    comes nearer to it than that value. Returns (count,) int64 indices."""
    total, nodes = placed.shape[0], child.shape[0]
    position = np.empty(total, dtype=np.int64)  # index -> row of placed
    for k in range(total):
        position[order[k]] = k
    value = np.full(nodes, np.inf)  # before the first sample every point is infinitely far
    index = np.zeros(nodes, dtype=np.int64)
    nearest = np.full(total, np.inf)  # squared distance to the nearest sample so far, placed order
    chosen = np.empty(count, dtype=np.int64)
    stack = np.empty(nodes, dtype=np.int64)
    visited = np.empty(nodes, dtype=np.int64)
    sample = 0
    for s in range(count):
        chosen[s] = sample
        row = position[sample]
        x, y, z = placed[row, 0], placed[row, 1], placed[row, 2]
        top, seen = 1, 0
        stack[0] = 0
        while top > 0:
            top -= 1
            node = stack[top]
            gx = max(max(low[node, 0] - x, 0.0), x - high[node, 0])
            gy = max(max(low[node, 1] - y, 0.0), y - high[node, 1])
            gz = max(max(low[node, 2] - z, 0.0), z - high[node, 2])
            if not gx * gx + gy * gy + gz * gz < value[node]:
                continue  # the sample is no nearer to any of the node's points than their nearest sample
            if child[node] < 0:
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
                stack[top] = child[node]
                stack[top + 1] = child[node] + 1
                top += 2
        for v in range(seen - 1, -1, -1):  # children before parents
            node = visited[v]
            left, right = child[node], child[node] + 1
            if value[right] > value[left] or (value[right] == value[left] and index[right] < index[left]):
                left = right
            value[node], index[node] = value[left], index[left]
        sample = index[0]
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
