"""Simulated pinhole range camera, ray cast against a mesh with open3d.

A scan is one ray per pixel, cast from the sensor position through the pixel centres. Rays
that hit the mesh between the near and far range return the hit point; the others return
nothing and carry a point beyond the far range along the ray, so that an integrator with a
maximum range (OctoMap's ``insertPointCloud(..., maxrange=far)``) carves free space up to the
far range and marks nothing occupied.

Same bytes on every CPU: open3d's Embree kernels find the triangle each ray hits, but their
distance arithmetic (SIMD width, fused multiply-adds) differs between instruction sets in the
last bits, enough to move a point across a voxel boundary now and then. So the ray directions
and each hit's distance (from the ray and the plane of the triangle Embree reports) are
computed here, in float64 with a fixed order of operations and no fused multiply-add
(numba without fastmath), and only the triangle ids come from Embree.

Which triangle a ray meets first is Embree's float32 decision wherever two triangles are at the
same depth within its doubt: at a shared edge, on duplicated or overlapping faces, where two
parts of an object cross. Another instruction set may give the ray to the other one, whose plane
puts the hit a few ulps away. The grids and coverage do not see that (a point moves into another
voxel or cell only within those ulps of a face); the partial clouds keep each point's exact
position, so they take it from the *canonical* triangle: among the triangles near the hit
(``TriangleCells``) that the ray meets within ``EDGE_TOLERANCE`` of their border and within
``DEPTH_WINDOW`` of the reported hit, the lowest-numbered of those within ``DEPTH_TOLERANCE`` of
the nearest - the same triangle whichever of them Embree reported (``Scan.cloud``;
``_canonical_distances``). A ray that passes within ``GRAZE_TOLERANCE`` of an *outline* of the
surface (an open edge, a silhouette) may hit on one CPU and pass beside it on another; the
clouds pass every such hit through (``_grazes``: eight rays around it must all meet the surface
there) and take what the ray meets beyond it, or nothing - what a CPU that let it pass finds.
The grids and coverage keep Embree's answers (a flipped ray changes a voxel's count only where no
other ray reaches it). A noisy sensor draws one range error per pixel, hit or not, so a flipped
ray changes no other ray's draw.

Only the rays that meet the mesh's bounding box (slightly enlarged) go to Embree: the others
cannot hit it. Embree traces every ray on its own, so the subset changes no ray's answer (tested
against casting every ray), and a scan of a small object costs a fraction of the full image.

Longer than 600 lines because the scan is one geometry: the camera's rays, their casting, the
exact hit distances and the scan's points belong together, and each is tested against the others.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator, NamedTuple, Sequence

import numba
import numpy as np
import trimesh

from nbvdata.core.config import SensorConfig
from nbvdata.core.views import Pose, ViewSet
from nbvdata.simulation._open3d import open3d as o3d

NO_HIT = np.uint32(2**32 - 1)  # Embree's primitive id of a ray that hits nothing
# A hit nearer than this to its triangle's border (metres, in the triangle's plane) may be given
# to a neighbour by another CPU's Embree, which decides in float32 (to about 1e-7 m here).
EDGE_TOLERANCE = 2.0**-18  # 3.8 um
# Candidates met this much farther along the ray than the nearest one are not the same hit.
DEPTH_TOLERANCE = 2.0**-20  # 0.95 um
# Triangles met this much nearer or farther than the reported hit are not candidates: wider than
# DEPTH_TOLERANCE plus Embree's doubt, so every candidate within DEPTH_TOLERANCE of the nearest is
# found from any of them.
DEPTH_WINDOW = 2.0**-17  # 7.6 um
# How far from a hit point a candidate can lie (along the ray, then in its plane), with room to spare.
REACH = 2.0 * (DEPTH_WINDOW + EDGE_TOLERANCE)
# A ray that passes this near the border of the surface it meets may, on another CPU, pass beside
# it where that border is an outline (``_grazes``): about 10 times Embree's float32 doubt here.
GRAZE_TOLERANCE = 2.0**-20  # 0.95 um
# How far across a ray its eight neighbours of the outline test lie: each crosses every edge within
# GRAZE_TOLERANCE of the ray whose outward side lies within 22.5 degrees of its offset.
GRAZE_OFFSET = 2.0 * GRAZE_TOLERANCE
# A neighbour that passes this near a triangle's border counts as inside it (the seams of a fan).
GRAZE_SEAM = 2.0**-24
# Outlines (or restarts) one ray may pass through before its cloud gives up on it (no point).
MAX_PASSES = 8
_EVERYWHERE = np.array([[-np.inf] * 3, [np.inf] * 3])  # a box every ray meets (MeshScanner(bounded=False))
# Rays per open3d call; bounds the rays buffer to about 64 views x 25k rays x 24 B = 40 MB.
_RAYS_PER_CALL = 64 * 176 * 144


@dataclass(frozen=True)
class Scan:
    """One range image, in the world frame.

    origin : (3,) float32 sensor position
    points : (N, 3) float32, N = width * height; the hit point of each ray, or for rays with
             no return a point at twice the far range along the ray
    hit : (N,) bool, True where the ray returned a measurement
    cloud : (K, 3) float32 the measured points as the partial clouds keep them, in ray order:
            each on its ray's canonical triangle, a grazed outline's hit replaced by what the
            ray meets beyond it or left out (module docstring), so K is about H; None:
            ``hit_points`` (a scan cast with ``cloud=False``, or not cast here, e.g. a real
            sensor's)
    """

    origin: np.ndarray
    points: np.ndarray
    hit: np.ndarray
    cloud: np.ndarray | None = None

    @property
    def hit_points(self) -> np.ndarray:
        """(H, 3) float32 the measured surface points only."""
        return self.points[self.hit]

    @property
    def cloud_points(self) -> np.ndarray:
        """(K, 3) float32 the measured points for a partial cloud: ``cloud``, else ``hit_points``."""
        return self.hit_points if self.cloud is None else self.cloud


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

    def __init__(self, mesh: trimesh.Trimesh, config: SensorConfig = SensorConfig(), threads: int = 0,
                 bounded: bool = True):
        """``threads``: open3d casting threads, 0 = all cores (parallel workers pass 1).
        ``bounded``: cast only the rays that meet the mesh's bounding box (False: every ray,
        the reference the tests compare against; the scans are the same)."""
        self.config = config
        self.threads = threads
        self._vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float32)
        self._faces = np.ascontiguousarray(mesh.faces, dtype=np.uint32)
        self._box = _enlarged_box(self._vertices) if bounded and len(self._vertices) else _EVERYWHERE
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(self._vertices), o3d.core.Tensor(self._faces))
        self._cells: TriangleCells | None = None  # built by the first scan that keeps its cloud
        self._camera_rays = camera_rays(config)
        self._tangents = np.array([np.tan(config.hfov / 2), np.tan(config.vfov / 2)])

    @property
    def rays_per_scan(self) -> int:
        return len(self._camera_rays)

    def scan(self, pose: Pose, rng: np.random.Generator | None = None, cloud: bool = True) -> Scan:
        """Scan from one pose; ``rng`` draws the range noise when ``noise_std`` > 0."""
        return self.scan_many([pose], rng, cloud=cloud)[0]

    def scan_many(self, poses: Sequence[Pose] | ViewSet, rng: np.random.Generator | None = None,
                  noiseless: bool = False, cloud: bool = True) -> list[Scan]:
        """Scan from many poses with as few open3d calls as memory allows.

        ``noiseless`` casts exact ranges even when the sensor has noise (for ground truth).
        ``cloud`` False leaves ``Scan.cloud`` None: the clouds' rules (canonical triangles,
        outlines passed through) cost 1-2 ms a scan, which a caller that only integrates grids or
        covers points need not pay (its ``points`` and ``hit`` are the same either way).
        """
        return list(self.iter_scans(poses, rng, noiseless, cloud))

    def iter_scans(self, poses: Sequence[Pose] | ViewSet, rng: np.random.Generator | None = None,
                   noiseless: bool = False, cloud: bool = True) -> Iterator[Scan]:
        """Like ``scan_many`` but yields scans batch by batch, so memory stays bounded."""
        if noiseless:
            rng = None
        elif self.config.noise_std > 0 and rng is None:
            raise ValueError("sensor.noise_std > 0 needs a numpy Generator: pass rng=np.random.default_rng(seed)")
        for positions, rotations in self._batches(poses):
            yield from self._cast(positions, rotations, rng, cloud)

    def iter_hit_points(self, poses: Sequence[Pose] | ViewSet) -> Iterator[np.ndarray]:
        """The (H, 3) float32 hit points of a noise-free scan from each pose, the same as
        ``scan.hit_points``, without the end points of the rays that return nothing."""
        for positions, rotations in self._batches(poses):
            rays, cast, _, t_cast = self._distances(positions, rotations, every=False)
            points, counts = _hit_points(rays, cast, t_cast, self.config.near, self.config.far,
                                         self.rays_per_scan, len(positions))
            yield from np.split(points, np.cumsum(counts)[:-1])

    def _batches(self, poses: Sequence[Pose] | ViewSet) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """(positions (B, 3), world-to-camera rotations (B, 3, 3)) float64, in as few batches as
        the rays buffer allows."""
        if isinstance(poses, ViewSet):
            positions, rotations = poses.positions, poses.rotations
        else:
            positions = np.array([p.position for p in poses], dtype=np.float64).reshape(-1, 3)
            rotations = np.array([p.rotation for p in poses], dtype=np.float64).reshape(-1, 3, 3)
        per_call = max(1, _RAYS_PER_CALL // self.rays_per_scan)
        for start in range(0, len(positions), per_call):
            yield positions[start:start + per_call], rotations[start:start + per_call]

    def _distances(self, positions: np.ndarray, rotations: np.ndarray,
                   every: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The rays of the views, and the distance to the first hit of those that may hit.

        Returns rays (V * N, 6) float32 (origin, direction; with ``every`` False only the rays
        near the mesh's box are set), cast (C,) int64 ascending indices of the rays cast (those
        meeting the box), triangles (C,) uint32 the triangle each hits (NO_HIT for none) and
        t_cast (C,) float64 their distance to its plane, inf for none.
        """
        n_views, n_rays = len(positions), self.rays_per_scan
        rays = np.empty((n_views * n_rays, 6), dtype=np.float32)
        near_box = np.empty(n_views * n_rays, dtype=np.bool_)
        _fill_rays(self._camera_rays, self.config.width, self._tangents, positions, rotations, self._box, every,
                   rays, near_box)
        cast = np.flatnonzero(near_box)
        t_cast = np.empty(len(cast), dtype=np.float64)
        triangles = self._triangles(rays[cast])
        plane_distances(rays, cast, triangles, self._vertices, self._faces, t_cast)
        return rays, cast, triangles, t_cast

    @property
    def cells(self) -> TriangleCells:
        """The mesh's ``TriangleCells``, built on first use."""
        if self._cells is None:
            self._cells = TriangleCells.build(self._vertices, self._faces)
        return self._cells

    def _cast(self, positions: np.ndarray, rotations: np.ndarray, rng: np.random.Generator | None,
              cloud: bool) -> list[Scan]:
        n_views, n_rays = len(positions), self.rays_per_scan
        rays, cast, triangles, t_cast = self._distances(positions, rotations)
        t_cloud = self._cloud_distances(rays, cast, triangles, t_cast) if cloud else None
        if rng is not None and self.config.noise_std > 0:
            # One draw per pixel of every image, in pixel order, whether its ray hits or not: a ray
            # that hits on one CPU and misses on another moves no other ray's draw; inf stays inf.
            noise = rng.normal(0.0, self.config.noise_std, n_views * n_rays)[cast]
            t_cast += noise
            if t_cloud is not None:
                t_cloud += noise  # the same draw for the same ray, also where it was passed through
        t_hit = np.full(n_views * n_rays, np.inf)
        t_hit[cast] = t_cast
        points = np.empty((n_views, n_rays, 3), dtype=np.float32)
        hit = np.empty((n_views, n_rays), dtype=bool)
        _end_points(rays, t_hit, self.config.near, self.config.far, points.reshape(-1, 3), hit.reshape(-1))
        clouds = [None] * n_views
        if t_cloud is not None:
            kept, counts = _hit_points(rays, cast, t_cloud, self.config.near, self.config.far, n_rays, n_views)
            clouds = np.split(kept, np.cumsum(counts)[:-1])  # on canonical triangles, outlines passed through
        return [Scan(rays[v * n_rays, :3].copy(), points[v], hit[v], clouds[v]) for v in range(n_views)]

    def _cloud_distances(self, rays: np.ndarray, cast: np.ndarray, triangles: np.ndarray,
                         t_cast: np.ndarray) -> np.ndarray:
        """(C,) float64 each cast ray's distance to its cloud point, inf for none (module docstring).

        The canonical triangle's plane (``_canonical_distances``); a hit that grazes an outline
        (``_grazes``) is passed through: the ray is cast again from DEPTH_WINDOW beyond it (by
        Embree, each distance then measured along the original ray), up to MAX_PASSES casts, so a
        CPU that lets it pass and one that does not find the same surface behind, or none.
        rays (M, 6) float32, cast (C,) int64, triangles (C,) uint32, t_cast (C,) float64.
        """
        t_cloud = np.empty(len(cast), dtype=np.float64)
        canon = np.empty(len(cast), dtype=np.int64)
        graze = np.empty(len(cast), dtype=np.bool_)
        self._canonical(rays, cast, triangles, t_cast, t_cloud, canon, graze)
        pending = np.flatnonzero(graze)  # cast again from t_from, each distance along its original ray
        t_from = t_cloud[pending] + DEPTH_WINDOW
        for _ in range(MAX_PASSES):
            if not len(pending):
                return t_cloud
            which = cast[pending]
            again = np.empty((len(pending), 6), dtype=np.float32)
            _beyond(rays, which, t_from, again)
            reported = self._triangles(again)
            t_again = np.empty(len(pending), dtype=np.float64)
            plane_distances(rays, which, reported, self._vertices, self._faces, t_again)
            early = t_again < t_from  # a surface at the restart itself, within Embree's doubt: look past it
            met = ~early
            t_now, canon_now, graze_now = (np.empty(int(met.sum()), dtype=dtype) for dtype in (np.float64, np.int64,
                                                                                            np.bool_))
            self._canonical(rays, which[met], reported[met], t_again[met], t_now, canon_now, graze_now)
            t_cloud[pending[met]] = t_now
            t_from = np.concatenate([t_from[early] + DEPTH_TOLERANCE, t_now[graze_now] + DEPTH_WINDOW])
            pending = np.concatenate([pending[early], pending[met][graze_now]])
        t_cloud[pending] = np.inf  # still passing outlines after MAX_PASSES casts: no point
        return t_cloud

    def _canonical(self, rays, cast, triangles, t_cast, t_cloud, canon, graze) -> None:
        """The canonical distances and triangles of the reported hits, and which of them graze an
        outline (``_canonical_distances``, ``_grazes``), into t_cloud, canon and graze (C,)."""
        gap = np.empty(len(cast), dtype=np.float64)
        _canonical_distances(rays, cast, triangles, t_cast, self._vertices, self._faces, *self.cells, t_cloud, canon,
                             gap)
        _grazes(rays, cast, t_cloud, canon, gap, self._vertices, self._faces, *self.cells, graze)

    def _triangles(self, rays: np.ndarray) -> np.ndarray:
        """(M,) uint32 the triangle each of ``rays`` (M, 6) float32 hits first, NO_HIT for none."""
        if not len(rays):
            return np.empty(0, dtype=np.uint32)
        return self._scene.cast_rays(o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays)),
                                     nthreads=self.threads)["primitive_ids"].numpy()


def _enlarged_box(vertices: np.ndarray) -> np.ndarray:
    """(2, 3) float64 the vertices' bounding box grown by 1e-4 of its diagonal plus 1 um on every
    side: far beyond the rounding of any hit Embree could report, so no hit lies outside."""
    low, high = vertices.min(axis=0).astype(np.float64), vertices.max(axis=0).astype(np.float64)
    margin = 1e-4 * float(np.linalg.norm(high - low)) + 1e-6
    return np.stack([low - margin, high + margin])


@numba.njit(cache=True, inline="always")
def half_line_meets_box(origin, direction, low, high):
    """Whether origin + t * direction, t >= 0, meets the box [low, high] (slab test; each
    argument a 3-tuple of float64; ``direction`` need not be a unit vector)."""
    enter, leave = 0.0, np.inf
    for a in range(3):
        if direction[a] == 0.0:
            if origin[a] < low[a] or origin[a] > high[a]:
                return False
            continue
        inverse = 1.0 / direction[a]
        near, far = (low[a] - origin[a]) * inverse, (high[a] - origin[a]) * inverse
        enter, leave = max(enter, min(near, far)), min(leave, max(near, far))
    return enter <= leave


@numba.njit(cache=True)
def _image_window(position, rotation, box, tangents, width, height):
    """(first row, last row, first column, last column) of the pixels whose rays may meet
    ``box``: the projections of its eight corners, one pixel wider on every side; the whole
    image when a corner is not in front of the camera (or the box is unbounded)."""
    whole = (0, height - 1, 0, width - 1)
    low_u, high_u, low_v, high_v = np.inf, -np.inf, np.inf, -np.inf
    for corner in range(8):
        camera = np.zeros(3)
        for a in range(3):
            offset = box[(corner >> a) & 1, a] - position[a]
            if not np.isfinite(offset):
                return whole
            for b in range(3):
                camera[b] += rotation[b, a] * offset
        if camera[2] <= 1e-9:
            return whole
        u, v = camera[0] / camera[2] / tangents[0], camera[1] / camera[2] / tangents[1]
        low_u, high_u, low_v, high_v = min(low_u, u), max(high_u, u), min(low_v, v), max(high_v, v)
    # pixel centre c sits at ((c + 0.5) / size) * 2 - 1
    first_col = max(int(math.floor((low_u + 1) / 2 * width - 0.5)) - 1, 0)
    last_col = min(int(math.ceil((high_u + 1) / 2 * width - 0.5)) + 1, width - 1)
    first_row = max(int(math.floor((low_v + 1) / 2 * height - 0.5)) - 1, 0)
    last_row = min(int(math.ceil((high_v + 1) / 2 * height - 0.5)) + 1, height - 1)
    return first_row, last_row, first_col, last_col


@numba.njit(cache=True)
def _fill_rays(camera_rays, width, tangents, positions, rotations, box, every, rays, near_box):
    """rays[v * N + i] = (origin, R_v^T @ camera_rays[i]) as float32, in a fixed order of
    operations, and near_box: whether that ray meets ``box`` at t >= 0 (slab test in float64,
    within the pixels ``_image_window`` leaves; the others cannot meet it).

    camera_rays (N, 3) float64 row-major over an image ``width`` wide, tangents (2,) the tangents
    of the half fields of view, positions (V, 3) float64, rotations (V, 3, 3) float64 world to
    camera, box (2, 3) float64 low and high corners; ``every``: fill every ray, else only those
    of the window (the others are left unset); rays (V * N, 6) float32 and near_box (V * N,)
    bool out.
    """
    count = camera_rays.shape[0]
    height = count // width
    low, high = (box[0, 0], box[0, 1], box[0, 2]), (box[1, 0], box[1, 1], box[1, 2])
    for v in range(positions.shape[0]):
        r = rotations[v]
        first_row, last_row, first_col, last_col = _image_window(positions[v], r, box, tangents, width, height)
        for row in range(height):
            row_inside = first_row <= row <= last_row
            if not (every or row_inside):
                near_box[v * count + row * width:v * count + (row + 1) * width] = False
                continue
            for col in range(width):
                i = row * width + col
                ray = v * count + i
                inside = row_inside and first_col <= col <= last_col
                if not (every or inside):
                    near_box[ray] = False
                    continue
                cx, cy, cz = camera_rays[i, 0], camera_rays[i, 1], camera_rays[i, 2]
                for a in range(3):
                    rays[ray, a] = positions[v, a]
                    rays[ray, 3 + a] = (cx * r[0, a] + cy * r[1, a]) + cz * r[2, a]
                near_box[ray] = inside and half_line_meets_box(
                    (np.float64(rays[ray, 0]), np.float64(rays[ray, 1]), np.float64(rays[ray, 2])),
                    (np.float64(rays[ray, 3]), np.float64(rays[ray, 4]), np.float64(rays[ray, 5])), low, high)


@numba.njit(cache=True, inline="always")
def _plane_hit(ox, oy, oz, dx, dy, dz, vertices, faces, f):
    """(t, nx, ny, nz): the distance along a ray (float64 origin and direction) to the plane of
    triangle ``f``, inf for a ray parallel to it, and the plane's normal (edge 1 x edge 2, not
    unit), in a fixed order of operations."""
    a, b, d = faces[f, 0], faces[f, 1], faces[f, 2]
    ax, ay, az = np.float64(vertices[a, 0]), np.float64(vertices[a, 1]), np.float64(vertices[a, 2])
    e1x, e1y, e1z = vertices[b, 0] - ax, vertices[b, 1] - ay, vertices[b, 2] - az
    e2x, e2y, e2z = vertices[d, 0] - ax, vertices[d, 1] - ay, vertices[d, 2] - az
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    along = (nx * dx + ny * dy) + nz * dz
    across = (nx * (ax - ox) + ny * (ay - oy)) + nz * (az - oz)
    return (across / along if along != 0.0 else np.inf), nx, ny, nz


@numba.njit(cache=True)
def plane_distances(rays, cast, triangle, vertices, faces, t_cast):
    """t_cast[c] = distance along ray cast[c] to the plane of the triangle it hit, inf for a miss.

    rays (M, 6) float32, cast (C,) int64 indices into rays, triangle (C,) uint32 (NO_HIT = no
    hit), vertices (P, 3) float32, faces (F, 3) uint32, t_cast (C,) float64 out. The float32
    inputs are exact in float64.
    """
    for c in range(cast.shape[0]):
        f = triangle[c]
        if f >= faces.shape[0]:
            t_cast[c] = np.inf
            continue
        i = cast[c]
        t_cast[c] = _plane_hit(np.float64(rays[i, 0]), np.float64(rays[i, 1]), np.float64(rays[i, 2]),
                               np.float64(rays[i, 3]), np.float64(rays[i, 4]), np.float64(rays[i, 5]),
                               vertices, faces, f)[0]


class TriangleCells(NamedTuple):
    """A uniform grid over the mesh's box: the triangles whose box, grown by ``REACH``, meets each
    cell - every triangle a ray could meet near a hit point is in the hit point's cell.

    low (3,) float64 the grid's corner, size float64 a cell's edge, shape (3,) int64 cells per
    axis, start (C + 1,) int64 and members (M,) int64: cell c's triangles are
    members[start[c]:start[c + 1]], ascending, with C = prod(shape) cells (x slowest)."""

    low: np.ndarray
    size: float
    shape: np.ndarray
    start: np.ndarray
    members: np.ndarray

    @classmethod
    def build(cls, vertices: np.ndarray, faces: np.ndarray, per_cell: float = 4.0) -> "TriangleCells":
        """Cells about ``per_cell`` triangles of a surface each (at most 64 a side), coarser where
        long triangles would fill more than ``16 F`` (at least 2^20) list entries. The cells only
        narrow the search: the canonical distances do not depend on them.

        vertices (P, 3) float32, faces (F, 3) integer."""
        if not len(faces):
            return cls(np.zeros(3), 1.0, np.ones(3, dtype=np.int64), np.zeros(2, dtype=np.int64),
                       np.zeros(0, dtype=np.int64))
        corners = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]  # (F, 3, 3)
        lows, highs = corners.min(axis=1) - REACH, corners.max(axis=1) + REACH
        low, span = lows.min(axis=0), highs.max(axis=0) - lows.min(axis=0)
        side = min(max(math.ceil(math.sqrt(len(faces) / per_cell)), 1), 64)  # a surface: cells in use ~ side^2
        while True:
            size = max(float(span.max()) / side, REACH)
            shape = np.maximum(np.ceil(span / size).astype(np.int64), 1)
            first = np.clip(np.floor((lows - low) / size).astype(np.int64), 0, shape - 1)
            last = np.clip(np.floor((highs - low) / size).astype(np.int64), 0, shape - 1)
            entries = int(np.prod(last - first + 1, axis=1).sum())
            if side == 1 or entries <= max(16 * len(faces), 2**20):
                break
            side //= 2
        start, members = _fill_cells(first, last, shape)
        return cls(low, size, shape, start, members)


@numba.njit(cache=True)
def _fill_cells(first, last, shape):
    """CSR lists of the triangles whose cell ranges first[f]..last[f] (inclusive, (F, 3)) cover
    each cell of a ``shape`` grid, each list ascending."""
    cells = shape[0] * shape[1] * shape[2]
    counts = np.zeros(cells + 1, dtype=np.int64)
    for f in range(first.shape[0]):
        for i in range(first[f, 0], last[f, 0] + 1):
            for j in range(first[f, 1], last[f, 1] + 1):
                for k in range(first[f, 2], last[f, 2] + 1):
                    counts[(i * shape[1] + j) * shape[2] + k + 1] += 1
    start = np.cumsum(counts)
    members = np.empty(start[-1], dtype=np.int64)
    fill = start[:-1].copy()
    for f in range(first.shape[0]):  # in triangle order: every list comes out ascending
        for i in range(first[f, 0], last[f, 0] + 1):
            for j in range(first[f, 1], last[f, 1] + 1):
                for k in range(first[f, 2], last[f, 2] + 1):
                    c = (i * shape[1] + j) * shape[2] + k
                    members[fill[c]] = f
                    fill[c] += 1
    return start, members


@numba.njit(cache=True)
def _triangle_hit(ox, oy, oz, dx, dy, dz, vertices, faces, f):
    """(t, margin, gap) of a ray (float64 origin and direction) and triangle ``f``: t its
    distance to the triangle's plane (as ``plane_distances``); margin how far that plane point
    lies inside the triangle (metres, in the plane): inside, its distance from the nearest edge;
    outside, minus its distance from the triangle (from the nearest point of an edge, not of the
    edge's line: behind the sharp corner of a sliver the lines stay near for hundreds of um);
    gap the least signed distance between the ray's line and an edge's line, what a
    perturbation of the ray must exceed to cross that edge - the quantity Embree's float32 doubt
    acts on (h |cos| / sin(ray, edge) for a plane point h inside the edge). margin and gap -inf
    for a degenerate triangle or a ray parallel to it."""
    t, nx, ny, nz = _plane_hit(ox, oy, oz, dx, dy, dz, vertices, faces, f)
    norm2 = (nx * nx + ny * ny) + nz * nz
    if not np.isfinite(t) or norm2 == 0.0:
        return t, -np.inf, -np.inf
    norm = math.sqrt(norm2)
    along = abs((nx * dx + ny * dy) + nz * dz)
    a, b, d = faces[f, 0], faces[f, 1], faces[f, 2]
    ax, ay, az = np.float64(vertices[a, 0]), np.float64(vertices[a, 1]), np.float64(vertices[a, 2])
    bx, by, bz = np.float64(vertices[b, 0]), np.float64(vertices[b, 1]), np.float64(vertices[b, 2])
    cx, cy, cz = np.float64(vertices[d, 0]), np.float64(vertices[d, 1]), np.float64(vertices[d, 2])
    px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
    margin, gap, outside = np.inf, np.inf, np.inf
    for edge in range(3):  # (start, end) = (a, b), (b, c), (c, a): inside is the positive side
        if edge == 0:
            sx, sy, sz, ex, ey, ez = ax, ay, az, bx, by, bz
        elif edge == 1:
            sx, sy, sz, ex, ey, ez = bx, by, bz, cx, cy, cz
        else:
            sx, sy, sz, ex, ey, ez = cx, cy, cz, ax, ay, az
        ux, uy, uz = ex - sx, ey - sy, ez - sz
        vx, vy, vz = px - sx, py - sy, pz - sz
        wx, wy, wz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        length = math.sqrt((ux * ux + uy * uy) + uz * uz)
        qx, qy, qz = dy * uz - dz * uy, dz * ux - dx * uz, dx * uy - dy * ux  # d x u: the ray across the edge
        across = math.sqrt((qx * qx + qy * qy) + qz * qz)
        if length == 0.0 or across == 0.0:
            return t, -np.inf, -np.inf
        inside = (wx * nx + wy * ny) + wz * nz
        margin = min(margin, inside / (norm * length))
        gap = min(gap, inside * along / (norm2 * across))
        s = min(max(((ux * vx + uy * vy) + uz * vz) / (length * length), 0.0), 1.0)  # nearest point of the edge
        rx, ry, rz = vx - s * ux, vy - s * uy, vz - s * uz
        outside = min(outside, math.sqrt((rx * rx + ry * ry) + rz * rz))
    return t, (margin if margin >= 0.0 else -outside), gap


@numba.njit(cache=True)
def _canonical_distances(rays, cast, triangle, t_cast, vertices, faces, low, size, shape, start, members, t_cloud,
                         canon, canon_gap):
    """t_cloud[c] = distance along ray cast[c] to the plane of its canonical triangle canon[c],
    canon_gap[c] the ray's gap to that triangle's border (``_triangle_hit``; -inf for canon -1).

    The candidates are the triangles of the hit point's cell (``TriangleCells``: ``low`` ..
    ``members``) that the ray meets within EDGE_TOLERANCE of their border and within DEPTH_WINDOW
    of the reported hit (``triangle[c]`` at ``t_cast[c]``); the canonical one is the
    lowest-numbered of those met within DEPTH_TOLERANCE of the nearest of them. Every triangle
    within Embree's doubt of the first hit is a candidate whichever of them Embree reported, so
    the choice is the same on every CPU. A miss: t_cloud inf, canon -1; no candidate (a
    triangle touched edge-on, its plane point farther than EDGE_TOLERANCE outside it; a
    degenerate one): the reported distance and canon -1 (``_grazes`` passes it)."""
    distances = np.empty(16)
    ids = np.empty(16, dtype=np.int64)
    gaps = np.empty(16)
    for c in range(cast.shape[0]):
        t = t_cast[c]
        t_cloud[c] = t
        canon[c] = -1
        canon_gap[c] = -np.inf
        if triangle[c] >= faces.shape[0] or not np.isfinite(t):
            continue
        i = cast[c]
        ox, oy, oz = np.float64(rays[i, 0]), np.float64(rays[i, 1]), np.float64(rays[i, 2])
        dx, dy, dz = np.float64(rays[i, 3]), np.float64(rays[i, 4]), np.float64(rays[i, 5])
        j0, j1 = _cell_range(ox + t * dx, oy + t * dy, oz + t * dz, low, size, shape, start)
        found, nearest = 0, np.inf
        for j in range(j0, j1):
            g = members[j]
            t_g = _plane_hit(ox, oy, oz, dx, dy, dz, vertices, faces, g)[0]
            if not abs(t_g - t) <= DEPTH_WINDOW or not t_g > 0.0:  # most of the cell: another depth
                continue
            _, margin, gap = _triangle_hit(ox, oy, oz, dx, dy, dz, vertices, faces, g)
            if margin >= -EDGE_TOLERANCE:
                if found == distances.shape[0]:  # very many triangles through one point
                    distances = np.concatenate((distances, distances))
                    ids = np.concatenate((ids, ids))
                    gaps = np.concatenate((gaps, gaps))
                distances[found] = t_g  # in triangle order
                ids[found] = g
                gaps[found] = gap
                found += 1
                nearest = min(nearest, t_g)
        for j in range(found):  # ascending: the first one within DEPTH_TOLERANCE is the lowest-numbered
            if distances[j] <= nearest + DEPTH_TOLERANCE:
                t_cloud[c] = distances[j]
                canon[c] = ids[j]
                canon_gap[c] = gaps[j]
                break


@numba.njit(cache=True, inline="always")
def _cell_range(px, py, pz, low, size, shape, start):
    """(first, end) of the ``TriangleCells`` members of the cell holding point p."""
    cx = min(max(int(math.floor((px - low[0]) / size)), 0), shape[0] - 1)
    cy = min(max(int(math.floor((py - low[1]) / size)), 0), shape[1] - 1)
    cz = min(max(int(math.floor((pz - low[2]) / size)), 0), shape[2] - 1)
    cell = (cx * shape[1] + cy) * shape[2] + cz
    return start[cell], start[cell + 1]


@numba.njit(cache=True)
def _grazes(rays, cast, t_cloud, canon, canon_gap, vertices, faces, low, size, shape, start, members, graze):
    """graze[c]: ray cast[c] passes within GRAZE_TOLERANCE of an outline of the surface at its
    canonical triangle canon[c] (met at t_cloud[c], the ray canon_gap[c] inside its border) - an
    open edge or a silhouette, where another CPU's Embree may let the ray through.

    The test, only where the ray passes within GRAZE_TOLERANCE of the canonical triangle's
    border: the eight rays parallel to it, GRAZE_OFFSET away in directions 45 degrees apart across
    it (each crosses any edge within GRAZE_TOLERANCE of the ray whose outward side is within
    22.5 degrees of its offset), must each pass inside some triangle whose plane the ray itself
    meets within DEPTH_WINDOW of the hit, meeting it within REACH of the hit point (so the
    triangle is in the hit point's cell) - the surface there. One that meets none has crossed an
    outline (or met a surface seen within 7 degrees of edge-on: it passes too). A surface behind
    the outline within DEPTH_WINDOW counts as covering it: a CPU that lets the ray through to it
    finds the outline's triangle among its candidates (``_canonical_distances``), nearer, so both
    keep it. A reported hit with no candidate at all (a triangle seen edge-on, touched within
    Embree's doubt; a degenerate one) passes too: no surface lies within DEPTH_WINDOW of it."""
    half = math.sqrt(0.5)
    across = np.array([(1.0, 0.0), (half, half), (0.0, 1.0), (-half, half), (-1.0, 0.0), (-half, -half),
                       (0.0, -1.0), (half, -half)])  # the eight directions, on (u, v)
    offsets = np.empty((8, 3))
    met = np.empty(8, dtype=np.bool_)
    for c in range(cast.shape[0]):
        graze[c] = canon[c] < 0 and np.isfinite(t_cloud[c])  # a hit with no candidate: an edge-on touch
        if canon[c] < 0 or canon_gap[c] >= GRAZE_TOLERANCE:
            continue
        i = cast[c]
        ox, oy, oz = np.float64(rays[i, 0]), np.float64(rays[i, 1]), np.float64(rays[i, 2])
        dx, dy, dz = np.float64(rays[i, 3]), np.float64(rays[i, 4]), np.float64(rays[i, 5])
        t = t_cloud[c]
        # u, v: a fixed orthonormal pair across the ray (d x the axis it is least along, then d x u)
        ax, ay, az = abs(dx), abs(dy), abs(dz)
        if ax <= ay and ax <= az:
            ux, uy, uz = 0.0, dz, -dy
        elif ay <= az:
            ux, uy, uz = -dz, 0.0, dx
        else:
            ux, uy, uz = dy, -dx, 0.0
        norm = math.sqrt((ux * ux + uy * uy) + uz * uz)
        ux, uy, uz = ux / norm, uy / norm, uz / norm
        vx, vy, vz = dy * uz - dz * uy, dz * ux - dx * uz, dx * uy - dy * ux
        norm = math.sqrt((vx * vx + vy * vy) + vz * vz)
        vx, vy, vz = vx / norm, vy / norm, vz / norm
        for k in range(8):  # the neighbours' origins
            a, b = across[k, 0], across[k, 1]
            offsets[k, 0] = ox + GRAZE_OFFSET * (a * ux + b * vx)
            offsets[k, 1] = oy + GRAZE_OFFSET * (a * uy + b * vy)
            offsets[k, 2] = oz + GRAZE_OFFSET * (a * uz + b * vz)
        met[:] = False
        unmet = 8
        j0, j1 = _cell_range(ox + t * dx, oy + t * dy, oz + t * dz, low, size, shape, start)
        for j in range(j0, j1):  # each triangle's depth once, for all eight
            g = members[j]
            if not abs(_plane_hit(ox, oy, oz, dx, dy, dz, vertices, faces, g)[0] - t) <= DEPTH_WINDOW:
                continue
            for k in range(8):
                if met[k]:
                    continue
                t_g, _, gap = _triangle_hit(offsets[k, 0], offsets[k, 1], offsets[k, 2], dx, dy, dz, vertices, faces, g)
                if gap >= -GRAZE_SEAM and (t_g - t) ** 2 + GRAZE_OFFSET**2 <= REACH**2:
                    met[k] = True
                    unmet -= 1
            if unmet == 0:
                break
        graze[c] = unmet > 0


@numba.njit(cache=True)
def _beyond(rays, cast, t_from, out):
    """out (C, 6) float32: rays cast[c] restarted at distance t_from[c] along them (in float64,
    then rounded), the same direction."""
    for c in range(cast.shape[0]):
        i = cast[c]
        for a in range(3):
            out[c, a] = np.float64(rays[i, a]) + t_from[c] * np.float64(rays[i, 3 + a])
            out[c, 3 + a] = rays[i, 3 + a]


@numba.njit(cache=True)
def _hit_points(rays, cast, t, near, far, rays_per_view, views):
    """The hit points of the cast rays at their distance t (near <= t[c] <= far: Embree's, or the
    clouds'), computed as ``_end_points`` does, in ray order: points (H, 3) float32 and counts
    (views,) int64 per view."""
    points = np.empty((cast.shape[0], 3), dtype=np.float32)
    counts = np.zeros(views, dtype=np.int64)
    h = 0
    for c in range(cast.shape[0]):
        if t[c] >= near and t[c] <= far:
            i = cast[c]
            for a in range(3):
                points[h, a] = np.float64(rays[i, a]) + t[c] * np.float64(rays[i, 3 + a])
            counts[i // rays_per_view] += 1
            h += 1
    return points[:h], counts


@numba.njit(cache=True)
def _end_points(rays, t_hit, near, far, points, hit):
    """hit[i] = near <= t_hit[i] <= far; points[i] = origin + range * direction, in float64,
    stored as float32, with range t_hit[i] for a hit and 2 * far otherwise.

    rays (M, 6) float32, t_hit (M,) float64, points (M, 3) float32 out, hit (M,) bool out.
    """
    miss_range = 2.0 * far
    for i in range(rays.shape[0]):
        t = t_hit[i]
        hit[i] = (t >= near) & (t <= far)
        t = t if hit[i] else miss_range
        points[i, 0] = np.float64(rays[i, 0]) + t * np.float64(rays[i, 3])
        points[i, 1] = np.float64(rays[i, 1]) + t * np.float64(rays[i, 4])
        points[i, 2] = np.float64(rays[i, 2]) + t * np.float64(rays[i, 5])
