"""Surface coverage: which reference points on the mesh the scans have observed.

Reference points are sampled uniformly on the mesh surface (seeded). A reference point is
covered when some scanned point lies within ``CoverageConfig.threshold`` of it: Euclidean
distance <= threshold by default, or the authors' axis-aligned box |dx|, |dy|, |dz| <
threshold. Coverage is the covered fraction of all reference points, and also of the
*observable* ones: those that at least one candidate view covers (from a hemisphere of views
the underside of the object is never visible, so only the observable figure can reach 1).
"""

from __future__ import annotations

from typing import Iterable

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from nbvdata.config import CoverageConfig
from nbvdata.sensor import MeshScanner, Scan
from nbvdata.views import ViewSet


class SurfaceCoverage:
    """Reference points of one mesh and the matching rule.

    points : (P, 3) float64 reference points on the surface
    observable : (P,) bool or None, set by ``set_observable``
    """

    def __init__(self, mesh: trimesh.Trimesh, config: CoverageConfig, rng: np.random.Generator):
        self.config = config
        points, _ = trimesh.sample.sample_surface(mesh, config.points, seed=rng)
        self.points = np.asarray(points, dtype=np.float64)
        self._p_norm = 2 if config.metric == "euclidean" else np.inf
        self.observable: np.ndarray | None = None

    def covered_by(self, scan_points: np.ndarray) -> np.ndarray:
        """(P,) bool: reference points matched by any of ``scan_points`` (M, 3)."""
        scan_points = np.asarray(scan_points, dtype=np.float64).reshape(-1, 3)
        covered = np.zeros(len(self.points), dtype=bool)
        if len(scan_points) == 0:
            return covered
        threshold = self.config.threshold
        # Only reference points inside the scan's padded bounding box can match.
        low, high = scan_points.min(axis=0) - threshold, scan_points.max(axis=0) + threshold
        candidates = np.flatnonzero(np.all((self.points >= low) & (self.points <= high), axis=1))
        if len(candidates) == 0:
            return covered
        tree = cKDTree(scan_points)
        distance, _ = tree.query(self.points[candidates], k=1, p=self._p_norm,
                                 distance_upper_bound=threshold * 1.000001)
        if self.config.metric == "euclidean":
            covered[candidates] = distance <= threshold
        else:
            covered[candidates] = distance < threshold
        return covered

    def covered_by_scans(self, scans: Iterable[Scan]) -> np.ndarray:
        """(P,) bool: reference points matched by the hit points of any of ``scans``."""
        covered = np.zeros(len(self.points), dtype=bool)
        for scan in scans:
            covered |= self.covered_by(scan.hit_points)
        return covered

    def set_observable(self, scanner: MeshScanner, views: ViewSet) -> np.ndarray:
        """Mark the reference points that at least one of ``views`` covers; returns that mask."""
        self.observable = self.covered_by_scans(scanner.iter_scans(views))
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
