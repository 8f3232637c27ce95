"""The slow, plain reference for ``InfoGainPlanner.scores``, used by tests/test_evaluate.py and
benchmarks/evaluate.py (which puts this folder on sys.path): sample each ray densely with numpy
instead of walking it with the DDA."""

from __future__ import annotations

import math

import numpy as np

from nbvtrain.planners import InfoGainPlanner


def sampled_scores(planner: InfoGainPlanner, probabilities: np.ndarray, view: int, rays: np.ndarray,
                   step: float = 2e-5) -> tuple[float, int, int]:
    """``planner.scores`` of one view over the ray indices ``rays``, found by sampling each ray
    every ``step`` metres (it can miss a voxel corner clipped by less than ``step``).
    probabilities (n, n, n) float32. Returns (information, known rays, unknown rays)."""
    n, resolution = planner.grid.size, planner.grid.resolution
    low, high = planner._box
    origin = planner._origins[view].astype(np.float64)
    information, known, unknown = 0.0, 0, 0
    for ray in rays:
        end = planner._ends[view, ray].astype(np.float64)
        length = np.linalg.norm(end - origin)
        points = origin + (end - origin) / length * np.arange(0.0, length, step)[:, None]
        keys = np.floor(points / resolution).astype(np.int64) + n // 2
        keys = keys[((keys >= 0) & (keys < n)).all(axis=1)]
        if not len(keys):
            continue  # the ray misses the grid (the fitted cube is smaller than the frustum)
        keys = keys[np.concatenate([[True], (np.diff(keys, axis=0) != 0).any(axis=1)])]  # voxels in order
        met = 0
        for i, j, k in keys:
            p = probabilities[i, j, k]
            in_box = low <= i < high and low <= j < high and low <= k < high
            if p > 0.5:
                met = met or (1 if in_box else 0)
                break
            if in_box and planner.unknown[0] <= p <= planner.unknown[1]:
                information += -(p * math.log(p) + (1 - p) * math.log(1 - p))
                met = met or 2
        known += met == 1
        unknown += met == 2
    return information, known, unknown
