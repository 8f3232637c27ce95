"""Simulated pinhole range camera, ray cast against a mesh with open3d.

A scan is one ray per pixel, cast from the sensor position through the pixel centres. Rays
that hit the mesh between the near and far range return the hit point; the others return
nothing and carry a point beyond the far range along the ray, so that an integrator with a
maximum range (OctoMap's ``insertPointCloud(..., maxrange=far)``) carves free space up to the
far range and marks nothing occupied.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np
import trimesh

from nbvdata._open3d import open3d as o3d
from nbvdata.config import SensorConfig
from nbvdata.views import Pose, ViewSet

# Rays per open3d call; bounds the rays buffer to about 64 views x 25k rays x 24 B = 40 MB.
_RAYS_PER_CALL = 64 * 176 * 144


@dataclass(frozen=True)
class Scan:
    """One range image, in the world frame.

    origin : (3,) float32 sensor position
    points : (N, 3) float32, N = width * height; the hit point of each ray, or for rays with
             no return a point at twice the far range along the ray
    hit : (N,) bool, True where the ray returned a measurement
    """

    origin: np.ndarray
    points: np.ndarray
    hit: np.ndarray

    @property
    def hit_points(self) -> np.ndarray:
        """(H, 3) float32 the measured surface points only."""
        return self.points[self.hit]


def camera_rays(config: SensorConfig) -> np.ndarray:
    """(height * width, 3) float64 unit ray directions in the camera frame (z forward, y down).

    Pixel centres of a pinhole camera whose image spans ``hfov`` x ``vfov``; row-major order.
    """
    half_w, half_h = np.tan(config.hfov / 2), np.tan(config.vfov / 2)
    u = (np.arange(config.width) + 0.5) / config.width * 2 - 1
    v = (np.arange(config.height) + 0.5) / config.height * 2 - 1
    x, y = np.meshgrid(u * half_w, v * half_h)
    rays = np.stack([x.ravel(), y.ravel(), np.ones(x.size)], axis=1)
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


class MeshScanner:
    """Casts range scans of one mesh; the open3d scene is built once, in the constructor."""

    def __init__(self, mesh: trimesh.Trimesh, config: SensorConfig = SensorConfig(), threads: int = 0):
        """``threads``: open3d casting threads, 0 = all cores (parallel workers pass 1)."""
        self.config = config
        self.threads = threads
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(
            o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
            o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
        )
        self._camera_rays = camera_rays(config)

    @property
    def rays_per_scan(self) -> int:
        return len(self._camera_rays)

    def scan(self, pose: Pose, rng: np.random.Generator | None = None) -> Scan:
        """Scan from one pose; ``rng`` draws the range noise when ``noise_std`` > 0."""
        return self.scan_many([pose], rng)[0]

    def scan_many(self, poses: Sequence[Pose] | ViewSet, rng: np.random.Generator | None = None,
                  noiseless: bool = False) -> list[Scan]:
        """Scan from many poses with as few open3d calls as memory allows.

        ``noiseless`` casts exact ranges even when the sensor has noise (for ground truth).
        """
        return list(self.iter_scans(poses, rng, noiseless))

    def iter_scans(self, poses: Sequence[Pose] | ViewSet, rng: np.random.Generator | None = None,
                   noiseless: bool = False) -> Iterator[Scan]:
        """Like ``scan_many`` but yields scans batch by batch, so memory stays bounded."""
        if isinstance(poses, ViewSet):
            positions, rotations = poses.positions, poses.rotations
        else:
            positions = np.array([p.position for p in poses], dtype=np.float64).reshape(-1, 3)
            rotations = np.array([p.rotation for p in poses], dtype=np.float64).reshape(-1, 3, 3)
        if noiseless:
            rng = None
        elif self.config.noise_std > 0 and rng is None:
            raise ValueError("sensor.noise_std > 0 needs a numpy Generator: pass rng=np.random.default_rng(seed)")
        per_call = max(1, _RAYS_PER_CALL // self.rays_per_scan)
        for start in range(0, len(positions), per_call):
            yield from self._cast(positions[start:start + per_call], rotations[start:start + per_call], rng)

    def _cast(self, positions: np.ndarray, rotations: np.ndarray, rng: np.random.Generator | None) -> list[Scan]:
        n_views, n_rays = len(positions), self.rays_per_scan
        origins = positions.astype(np.float32)
        # world direction = R^T @ camera direction, for every view at once: (V, N, 3)
        directions = np.matmul(self._camera_rays[None], rotations).astype(np.float32)
        rays = np.empty((n_views, n_rays, 6), dtype=np.float32)
        rays[..., :3] = origins[:, None, :]
        rays[..., 3:] = directions
        t_hit = self._scene.cast_rays(o3d.core.Tensor(rays.reshape(-1, 6)), nthreads=self.threads)["t_hit"].numpy()
        t_hit = t_hit.reshape(n_views, n_rays)
        if rng is not None and self.config.noise_std > 0:
            finite = np.isfinite(t_hit)
            t_hit[finite] += rng.normal(0.0, self.config.noise_std, int(finite.sum())).astype(np.float32)
        hit = (t_hit >= self.config.near) & (t_hit <= self.config.far)
        ranges = np.where(hit, t_hit, np.float32(2 * self.config.far))
        points = origins[:, None, :] + ranges[..., None] * directions
        return [Scan(origins[v], points[v], hit[v]) for v in range(n_views)]
