"""What a plan costs a robot to travel: the shortest path between camera centres that does not
enter the object's bounding sphere, and the shortest order to visit a set of views.

The path from a to b around a sphere of radius r about the origin (ObjView-Bench's path cost,
their cameras at radius 3 around a unit sphere; ours at ``views.radius`` around the object's
bounding sphere): the straight segment when it stays at least r from the origin (or when an end
lies inside the sphere), else the tangent from a to the sphere, the great-circle arc, and the
tangent to b: sqrt(|a|^2 - r^2) + sqrt(|b|^2 - r^2) + r (theta - acos(r / |a|) - acos(r / |b|)),
theta the angle between a and b. Everything is float64; a path has no direction.

``shortest_tour``: the order that visits every view once from a start with the least total
path (an open tour: no return). Exact by Held-Karp's dynamic programme for up to
``EXACT_TOUR`` views, else nearest neighbour improved by 2-opt until no exchange shortens it:
deterministic, ties to the lowest index.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

EXACT_TOUR = 10  # views visited exactly (Held-Karp: 2^n n^2 steps) at most; a heuristic above


def path_length(a: np.ndarray, b: np.ndarray, radius: float) -> float:
    """Length of the shortest path from ``a`` to ``b`` ((3,) metres) that does not enter the
    sphere of ``radius`` about the origin (module docstring)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    ra, rb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    chord = float(np.linalg.norm(b - a))
    if chord == 0.0 or ra <= radius or rb <= radius:
        return chord
    # nearest point of the segment to the origin: a + s (b - a), s clamped to [0, 1]
    s = min(max(-float(a @ (b - a)) / chord**2, 0.0), 1.0)
    if float(np.linalg.norm(a + s * (b - a))) >= radius:
        return chord
    theta = math.acos(min(max(float(a @ b) / (ra * rb), -1.0), 1.0))
    arc = theta - math.acos(radius / ra) - math.acos(radius / rb)
    return math.sqrt(ra * ra - radius * radius) + math.sqrt(rb * rb - radius * radius) + radius * max(arc, 0.0)


def path_lengths(positions: np.ndarray, radius: float) -> np.ndarray:
    """(N,) float64 the path travelled to reach each of ``positions`` (N, 3) in order, the first 0."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    steps = [0.0] + [path_length(positions[i - 1], positions[i], radius) for i in range(1, len(positions))]
    return np.cumsum(steps)


def distance_matrix(positions: np.ndarray, radius: float) -> np.ndarray:
    """(N, N) float64 ``path_length`` between every pair of ``positions`` (N, 3)."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    count = len(positions)
    matrix = np.zeros((count, count))
    for i in range(count):
        for j in range(i + 1, count):
            matrix[i, j] = matrix[j, i] = path_length(positions[i], positions[j], radius)
    return matrix


def shortest_tour(start: np.ndarray, positions: np.ndarray, radius: float) -> list[int]:
    """The order (indices into ``positions`` (N, 3)) to visit every position once from ``start``
    (3,) with the least total ``path_length``: exact up to ``EXACT_TOUR`` positions, else nearest
    neighbour then 2-opt (module docstring)."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    count = len(positions)
    if count <= 1:
        return list(range(count))
    matrix = distance_matrix(np.concatenate([np.asarray(start, dtype=np.float64)[None], positions]), radius)
    if count <= EXACT_TOUR:
        return [i - 1 for i in _held_karp(matrix)]
    return [i - 1 for i in _two_opt(matrix, _nearest_neighbour(matrix))]


def tour_cost(matrix: np.ndarray, order: list[int]) -> float:
    """Total of ``matrix`` along node 0 (the start), then ``order``."""
    nodes = [0, *order]
    return float(sum(matrix[nodes[k], nodes[k + 1]] for k in range(len(nodes) - 1)))


def _held_karp(matrix: np.ndarray) -> list[int]:
    """The exact shortest open path from node 0 through every other node of ``matrix`` (nodes
    1..n): Held-Karp over subsets, ties to the lexicographically smallest order."""
    n = len(matrix) - 1
    best: dict[tuple[int, int], tuple[float, tuple[int, ...]]] = {}
    for j in range(1, n + 1):
        best[(1 << (j - 1), j)] = (matrix[0, j], (j,))
    for size in range(2, n + 1):
        for subset in itertools.combinations(range(1, n + 1), size):
            bits = sum(1 << (k - 1) for k in subset)
            for j in subset:
                rest = bits & ~(1 << (j - 1))
                best[(bits, j)] = min((best[(rest, k)][0] + matrix[k, j], best[(rest, k)][1] + (j,))
                                      for k in subset if k != j)
    full = (1 << n) - 1
    return list(min(best[(full, j)] for j in range(1, n + 1))[1])


def _nearest_neighbour(matrix: np.ndarray) -> list[int]:
    """From node 0, always the nearest node not visited (ties to the lowest index)."""
    left, order, here = set(range(1, len(matrix))), [], 0
    while left:
        here = min(left, key=lambda node: (matrix[here, node], node))
        order.append(here)
        left.remove(here)
    return order


def _two_opt(matrix: np.ndarray, order: list[int]) -> list[int]:
    """``order`` improved by reversing segments while one shortens the open path (first
    improvement, scanned in index order): a local optimum, deterministic."""
    order = list(order)
    improved = True
    while improved:
        improved = False
        nodes = [0, *order]
        for i in range(1, len(nodes) - 1):
            for k in range(i + 1, len(nodes)):
                before = matrix[nodes[i - 1], nodes[i]] + (matrix[nodes[k], nodes[k + 1]] if k + 1 < len(nodes) else 0)
                after = matrix[nodes[i - 1], nodes[k]] + (matrix[nodes[i], nodes[k + 1]] if k + 1 < len(nodes) else 0)
                if after < before - 1e-12:
                    nodes[i:k + 1] = nodes[i:k + 1][::-1]
                    improved = True
        order = nodes[1:]
    return order
