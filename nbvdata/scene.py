"""One object in the reconstruction scene: its mesh, the candidate views, the sensor and the
coverage reference, built once per mesh and shared by everything that simulates it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nbvdata.config import SimConfig
from nbvdata.coverage import SurfaceCoverage
from nbvdata.grid import OccupancyGrid
from nbvdata.mesh import ObjectMesh
from nbvdata.sensor import MeshScanner, Scan
from nbvdata.views import ViewSet, view_sphere


@dataclass
class Scene:
    """Everything fixed during the reconstructions of one object."""

    config: SimConfig
    object: ObjectMesh
    views: ViewSet
    scanner: MeshScanner
    coverage: SurfaceCoverage

    @classmethod
    def build(cls, obj: ObjectMesh, config: SimConfig, rng: np.random.Generator) -> "Scene":
        """Cast the scene; ``rng`` draws the coverage reference points. Marks what the views can observe."""
        views = view_sphere(config.views)
        scanner = MeshScanner(obj.mesh, config.sensor)
        coverage = SurfaceCoverage(obj.mesh, config.coverage, rng)
        coverage.set_observable(scanner, views)
        return cls(config, obj, views, scanner, coverage)

    def new_grid(self) -> OccupancyGrid:
        return OccupancyGrid(self.config.grid)

    def integrate(self, grid: OccupancyGrid, scan: Scan) -> None:
        """Insert a scan with the sensor's far range as OctoMap's maximum range."""
        grid.integrate(scan, self.config.sensor.far)
