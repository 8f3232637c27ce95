"""One object in the reconstruction scene: its mesh, the candidate views, the sensor, the
coverage reference and the exhaustive-search oracle, built once per mesh and shared by
everything that simulates it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nbvdata.core.config import SimConfig
from nbvdata.core.views import ViewSet, view_sphere
from nbvdata.simulation.coverage import SurfaceCoverage
from nbvdata.simulation.grid import OccupancyGrid
from nbvdata.simulation.mesh import ObjectMesh
from nbvdata.simulation.oracle import ViewOracle
from nbvdata.simulation.sensor import MeshScanner, Scan
from nbvdata.simulation.setcover import Cover, solve_cover


@dataclass
class Scene:
    """Everything fixed during the reconstructions of one object."""

    config: SimConfig
    object: ObjectMesh
    views: ViewSet
    scanner: MeshScanner
    coverage: SurfaceCoverage
    oracle: ViewOracle
    _empty_cover: Cover | None = field(default=None, repr=False)
    _covers: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, obj: ObjectMesh, config: SimConfig, rng: np.random.Generator, threads: int = 0) -> "Scene":
        """Cast the scene; ``rng`` draws the coverage reference points.

        Scans the object once from every candidate view (noise-free) to record what each view
        covers: the oracle's bit matrix, and the observable points (their union).
        ``threads`` limits the ray casting threads (0 = all cores).
        """
        views = view_sphere(config.views)
        scanner = MeshScanner(obj.mesh, config.sensor, threads)
        coverage = SurfaceCoverage(obj.mesh, config.coverage, rng)
        visible = coverage.covered_by_views(scanner, views)
        coverage.observable = visible.any(axis=0)
        return cls(config, obj, views, scanner, coverage, ViewOracle(visible))

    @property
    def bounding_radius(self) -> float:
        """Radius (metres) of the sphere about the origin - the views' centre - that holds the
        object: what a path between views must go round (``nbvdata.core.paths``)."""
        vertices = np.asarray(self.object.mesh.vertices, dtype=np.float64)
        return float(np.sqrt((vertices * vertices).sum(axis=1)).max()) if len(vertices) else 0.0

    def plan_cover(self, covered: np.ndarray) -> Cover:
        """The set cover of the state whose covered points are ``covered`` ((W,) packed), the
        solver's optimal set (``solve_cover(..., canonical=False)``), solved once per state: a
        start's floor and the setcover planner's plan from that start are one solve."""
        key = covered.tobytes()
        if key not in self._covers:
            self._covers[key] = solve_cover(self.oracle, covered, self.config.oracle.cover_node_limit, canonical=False)
        return self._covers[key]

    def empty_cover(self) -> Cover:
        """The set cover of the whole observable surface (no view scanned), solved on the first
        call: it bounds every run's first state (``nbvdata.simulation.setcover.next_cover``)."""
        if self._empty_cover is None:
            nothing = np.zeros_like(self.oracle.observable)
            self._empty_cover = solve_cover(self.oracle, nothing, self.config.oracle.cover_node_limit)
        return self._empty_cover

    def surface_voxels(self) -> np.ndarray:
        """(n, n, n) bool: the voxels of the scene grid (``config.scene_grid``, indexed as the
        occupancy grid) that the mesh's surface passes through - where a scan could mark a voxel
        occupied. The mesh is subdivided until every edge is under a quarter voxel (midpoints only:
        the same bytes on every CPU) and every vertex marks its voxel, so a triangle marks each
        voxel it crosses by more than a sliver."""
        import trimesh

        grid = self.config.scene_grid
        n, resolution = grid.size, grid.resolution
        vertices = np.asarray(self.object.mesh.vertices, dtype=np.float64)
        faces = np.asarray(self.object.mesh.faces, dtype=np.int64)
        vertices, _ = trimesh.remesh.subdivide_to_size(vertices, faces, max_edge=resolution / 4, max_iter=40)
        keys = np.floor(vertices / resolution).astype(np.int64) + n // 2
        keys = keys[((keys >= 0) & (keys < n)).all(axis=1)]
        surface = np.zeros((n, n, n), dtype=bool)
        surface[keys[:, 0], keys[:, 1], keys[:, 2]] = True
        return surface

    def new_grid(self) -> OccupancyGrid:
        return OccupancyGrid(self.config.scene_grid)

    def integrate(self, grid: OccupancyGrid, scan: Scan) -> None:
        """Insert a scan with the sensor's far range as OctoMap's maximum range."""
        grid.integrate(scan, self.config.sensor.far)
