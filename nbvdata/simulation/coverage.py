"""Surface coverage: which reference points on the mesh the scans have observed.

Reference points are sampled uniformly on the mesh surface (seeded). A reference point is
covered when some scanned point lies within ``CoverageConfig.threshold`` of it: Euclidean
distance <= threshold by default, or the authors' axis-aligned box |dx|, |dy|, |dz| <
threshold. Coverage is the covered fraction of all reference points, and also of the
*observable* ones: those that at least one candidate view covers (from a hemisphere of views
the underside of the object is never visible, so only the observable figure can reach 1).
"""

from __future__ import annotations

import math
from typing import Iterable

import numba
import numpy as np
import trimesh

from nbvdata.core.config import CoverageConfig
from nbvdata.core.views import ViewSet
from nbvdata.simulation.sensor import MeshScanner, Scan


class SurfaceCoverage:
    """Reference points of one mesh and the matching rule.

    points : (P, 3) float64 reference points on the surface
    observable : (P,) bool or None, set by ``set_observable``
    """

    def __init__(self, mesh: trimesh.Trimesh, config: CoverageConfig, rng: np.random.Generator):
        self.config = config
        points, _ = trimesh.sample.sample_surface(mesh, config.points, seed=rng)
        self.points = np.asarray(points, dtype=np.float64)
        self.observable: np.ndarray | None = None
        # Bucket the reference points into cubes of side >= threshold: every match of a scan
        # point then lies in the 27 cubes around its own.
        self._cell = config.threshold * 1.001
        self._low = self.points.min(axis=0) - config.threshold
        self._dims = (np.floor((self.points.max(axis=0) + config.threshold - self._low) / self._cell)
                      .astype(np.int64) + 1)
        cells = _cell_ids(self.points, self._low, self._cell, self._dims)
        # The points sorted by cell: a cell's points, and a row of three cells, are contiguous.
        self._cell_order = np.argsort(cells, kind="stable")
        self._sorted_points = np.ascontiguousarray(self.points[self._cell_order])
        self._cell_start = np.searchsorted(cells[self._cell_order], np.arange(int(np.prod(self._dims)) + 1))

    def covered_by(self, scan_points: np.ndarray) -> np.ndarray:
        """(P,) bool: reference points matched by any of ``scan_points`` (M, 3)."""
        scan_points = np.ascontiguousarray(scan_points, dtype=np.float64).reshape(-1, 3)
        covered_sorted = np.zeros(len(self.points), dtype=bool)
        _match_points(scan_points, self._sorted_points, self._cell_start, self._low, self._cell, self._dims,
                      self.config.threshold, self.config.metric == "box", covered_sorted)
        covered = np.empty(len(self.points), dtype=bool)
        covered[self._cell_order] = covered_sorted
        return covered

    def covered_by_scans(self, scans: Iterable[Scan]) -> np.ndarray:
        """(P,) bool: reference points matched by the hit points of any of ``scans``."""
        covered = np.zeros(len(self.points), dtype=bool)
        for scan in scans:
            covered |= self.covered_by(scan.hit_points)
        return covered

    def covered_by_views(self, scanner: MeshScanner, views: ViewSet) -> np.ndarray:
        """(V, P) bool: the reference points a noise-free scan from each view covers."""
        covered = np.zeros((len(views), len(self.points)), dtype=bool)
        for v, hit_points in enumerate(scanner.iter_hit_points(views)):
            covered[v] = self.covered_by(hit_points)
        return covered

    def set_observable(self, scanner: MeshScanner, views: ViewSet) -> np.ndarray:
        """Mark the reference points that at least one of ``views`` covers; returns that mask."""
        self.observable = self.covered_by_views(scanner, views).any(axis=0)
        return self.observable

    def coverage(self, covered: np.ndarray) -> tuple[float, float]:
        """(fraction of all reference points, fraction of the observable ones) that are covered.

        The second figure is NaN until ``set_observable`` has run.
        """
        covered = np.asarray(covered, dtype=bool)
        total = float(np.count_nonzero(covered)) / len(self.points)
        if self.observable is None:
            return total, float("nan")
        observable = int(np.count_nonzero(self.observable))
        seen = int(np.count_nonzero(covered & self.observable))
        return total, (seen / observable if observable else float("nan"))


def _cell_ids(points: np.ndarray, low: np.ndarray, cell: float, dims: np.ndarray) -> np.ndarray:
    index = np.floor((points - low) / cell).astype(np.int64)
    return (index[:, 0] * dims[1] + index[:, 1]) * dims[2] + index[:, 2]


@numba.njit(cache=True)
def _match_points(scan_points, reference, cell_start, low, cell, dims, threshold, box, covered):
    """Set covered[r] for every reference point r within ``threshold`` of some scan point.

    ``reference`` (P, 3) sorted by cell, cell c's points at [cell_start[c], cell_start[c + 1]);
    ``covered`` (P,) in the same order.
    """
    limit = threshold * threshold
    for m in range(scan_points.shape[0]):
        x, y, z = scan_points[m, 0], scan_points[m, 1], scan_points[m, 2]
        ci = int(math.floor((x - low[0]) / cell))
        cj = int(math.floor((y - low[1]) / cell))
        ck = int(math.floor((z - low[2]) / cell))
        if ci < -1 or cj < -1 or ck < -1 or ci > dims[0] or cj > dims[1] or ck > dims[2]:
            continue  # farther than one cell from every reference point
        k_first, k_last = max(ck - 1, 0), min(ck + 2, dims[2])
        for i in range(max(ci - 1, 0), min(ci + 2, dims[0])):
            for j in range(max(cj - 1, 0), min(cj + 2, dims[1])):
                base = (i * dims[1] + j) * dims[2]
                for r in range(cell_start[base + k_first], cell_start[base + k_last]):  # a row of cells
                    if covered[r]:
                        continue
                    dx = reference[r, 0] - x
                    dy = reference[r, 1] - y
                    dz = reference[r, 2] - z
                    if box:
                        if abs(dx) < threshold and abs(dy) < threshold and abs(dz) < threshold:
                            covered[r] = True
                    elif dx * dx + dy * dy + dz * dz <= limit:
                        covered[r] = True
