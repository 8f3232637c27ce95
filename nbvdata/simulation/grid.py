"""Probabilistic occupancy grid over the object cube, with OctoMap's exact update semantics.

The grid is ``size``^3 voxels of side ``extent / size`` covering the cube centred on the
origin. Its voxels coincide with the leaves of an OctoMap octree of the same resolution (the
cube's corner lies on a key boundary), and integrating a scan reproduces
``OcTree.insertPointCloud(points, origin, maxrange=far)`` voxel for voxel:

- every ray is walked with OctoMap's own 3D-DDA (``computeRayKeys``), in the same float32 and
  float64 arithmetic, from the sensor to its end point; the voxels passed are free, the end
  voxel is occupied; a ray longer than the far range is cut there and marks nothing occupied;
- within one scan a voxel is updated at most once, and a hit wins over a miss;
- log-odds are float32, updates add logodds(prob_hit) or logodds(prob_miss), then clamp.

Voxel [i, j, k] spans x, y, z = origin + ([i, j, k] + [0, 1]) * resolution. Exported
probabilities use the authors' encoding: float32, exactly 0.5 for never-observed voxels.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numba
import numpy as np

from nbvdata.core.config import GridConfig, SimConfig
from nbvdata.core.logodds import logodds, probability
from nbvdata.simulation.sensor import Scan, half_line_meets_box

if "NUMBA_THREADING_LAYER" not in os.environ:
    # Try OpenMP before TBB: pip's TBB is often too old for numba, which then warns on every run.
    numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]


@dataclass(frozen=True)
class ScanUpdate:
    """The voxels one scan updates, as flat C-order indices into the grid.

    occupied : (K,) int32 voxels holding a ray's end point (get the hit log-odds)
    free : (F,) int32 voxels only passed through (get the miss log-odds); disjoint from occupied
    """

    occupied: np.ndarray
    free: np.ndarray


class OccupancyGrid:
    """Log-odds occupancy grid; ``integrate`` scans, read ``probabilities()``.

    log_odds : (n, n, n) float32, 0 where nothing was observed
    observed : (n, n, n) bool, True once any ray has updated the voxel
    """

    def __init__(self, config: GridConfig | None = None):
        """``config`` with its cube in metres (``SimConfig.scene_grid``); None: the default scene's."""
        if config is None:
            config = SimConfig().scene_grid
        self.config = config
        n = config.size
        self.resolution = config.resolution
        # Key of the grid's first voxel in OctoMap's key space (without its 2^15 offset).
        self.first_key = -(n // 2)
        self.origin = self.first_key * self.resolution
        self.log_odds = np.zeros((n, n, n), dtype=np.float32)
        self.observed = np.zeros((n, n, n), dtype=bool)
        self._hit = logodds(config.prob_hit)
        self._miss = logodds(config.prob_miss)
        self._clamp = (logodds(config.clamp_min), logodds(config.clamp_max))
        self._free_mark = np.zeros((n, n, n), dtype=np.uint8)
        self._occupied_mark = np.zeros((n, n, n), dtype=np.uint8)

    @property
    def size(self) -> int:
        return self.config.size

    def integrate(self, scan: Scan, max_range: float) -> None:
        """Insert one scan, as OctoMap's insertPointCloud(points, origin, maxrange=max_range)."""
        self.apply(self.scan_update(scan, max_range))

    def scan_update(self, scan: Scan, max_range: float) -> "ScanUpdate":
        """The voxels ``scan`` occupies and frees; independent of the grid's state, so reusable.

        A noise-free scan from a fixed view always gives the same update: ``nbvdata.simulation.episode``
        computes it once per (mesh, view) and applies it as often as the view is scanned.
        """
        points = np.ascontiguousarray(scan.points, dtype=np.float32)
        origin = np.ascontiguousarray(scan.origin, dtype=np.float32)
        self._free_mark[...] = 0
        self._occupied_mark[...] = 0
        low = self.first_key * self.resolution - _NEAR_GRID
        high = (self.first_key + self.size) * self.resolution + _NEAR_GRID
        rays = _rays_near_grid(origin, points, low, high)
        _mark_rays(origin, points, rays, float(max_range), self.resolution, self.first_key,
                   self._free_mark, self._occupied_mark)
        occupied = np.flatnonzero(self._occupied_mark).astype(np.int32)
        free = np.flatnonzero((self._free_mark != 0) & (self._occupied_mark == 0)).astype(np.int32)
        return ScanUpdate(occupied, free)

    def apply(self, update: "ScanUpdate") -> None:
        """One update per voxel of ``update``: add the hit log-odds where occupied, the miss
        log-odds where free, then clamp (a hit wins over a miss: the sets are disjoint)."""
        _apply_update(self.log_odds.reshape(-1), self.observed.reshape(-1), update.occupied,
                      self._hit, self._clamp[0], self._clamp[1])
        _apply_update(self.log_odds.reshape(-1), self.observed.reshape(-1), update.free,
                      self._miss, self._clamp[0], self._clamp[1])

    def probabilities(self) -> np.ndarray:
        """(n, n, n) float32 occupancy probability; exactly 0.5 where unknown (authors' encoding)."""
        return np.where(self.observed, probability(self.log_odds), np.float32(0.5))

    def counts(self) -> dict[str, int]:
        """Voxels that are occupied (p > 0.5), free (p < 0.5) and unknown (never observed or p = 0.5)."""
        occupied = int(np.count_nonzero(self.observed & (self.log_odds > 0)))
        free = int(np.count_nonzero(self.observed & (self.log_odds < 0)))
        return {"occupied": occupied, "free": free, "unknown": self.log_odds.size - occupied - free}

    def voxel_centres(self) -> np.ndarray:
        """(n, n, n, 3) float64 world coordinates of every voxel centre."""
        axis = self.origin + (np.arange(self.size) + 0.5) * self.resolution
        return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1)


# ---------------------------------------------------------------------------------------------
# Compiled kernels. Names and arithmetic follow OctoMap's OcTreeBaseImpl::computeRayKeys and
# OccupancyOcTreeBase::computeUpdate; float32 where OctoMap uses float, float64 where double.


@numba.njit(cache=True, inline="always")
def _coord_to_key(coordinate, inv_resolution):
    return np.int64(math.floor(inv_resolution * np.float64(coordinate)))


@numba.njit(cache=True, inline="always")
def _mark(mark, key0, key1, key2, first_key, n):
    i, j, k = key0 - first_key, key1 - first_key, key2 - first_key
    if 0 <= i < n and 0 <= j < n and 0 <= k < n:
        mark[i, j, k] = 1
        return True
    return False


@numba.njit(cache=True, inline="always")
def _axis_setup(key, origin, direction, resolution):
    """OctoMap's per-axis DDA start: (step, t_max, t_delta) for one axis."""
    if direction > 0.0:
        step = 1
    elif direction < 0.0:
        step = -1
    else:
        return 0, np.inf, np.inf
    border = (np.float64(key) + 0.5) * resolution  # keyToCoord
    border += np.float64(np.float32(step * resolution * 0.5))
    t_max = (border - np.float64(origin)) / np.float64(direction)
    t_delta = resolution / abs(np.float64(direction))
    return step, t_max, t_delta


@numba.njit(cache=True, inline="always")
def _keys_before_grid(key, step, first_key, n):
    """Steps along one axis before its key enters [first_key, first_key + n); -1 if never."""
    if first_key <= key < first_key + n:
        return 0
    if step > 0 and key < first_key:
        return first_key - key
    if step < 0 and key >= first_key + n:
        return key - (first_key + n - 1)
    return -1


@numba.njit(cache=True, inline="always")
def _beyond_far_side(key, step, first_key, n):
    return (step > 0 and key >= first_key + n) or (step < 0 and key < first_key)


@numba.njit(cache=True, inline="always")
def _end_not_before_grid(end0, end1, end2, s0, s1, s2, first_key, n):
    """True when the walk cannot reach the end voxel before it enters the grid."""
    last = first_key + n
    if first_key <= end0 < last and first_key <= end1 < last and first_key <= end2 < last:
        return True
    return (_beyond_far_side(end0, s0, first_key, n) or _beyond_far_side(end1, s1, first_key, n)
            or _beyond_far_side(end2, s2, first_key, n))


@numba.njit(cache=True, inline="always")
def _advance(key, t, step, delta, count):
    for _ in range(count):
        key += step
        t += delta
    return key, t


@numba.njit(cache=True, inline="always")
def _advance_before(key, t, step, delta, axis, entry_t, entry_axis):
    """Take this axis's crossings that the DDA takes before the crossing (entry_t, entry_axis).

    The DDA takes the smallest pending t first and, among equal t, the highest axis.
    """
    count = 0
    while t < entry_t or (t == entry_t and axis > entry_axis):
        key += step
        t += delta
        count += 1
    return key, t, count


# How far (metres) a ray's line may pass from the grid and still be walked. A walk's crossing
# times stray from the exact line's by about 1e-13 m here, so a line farther away than this
# never has a key in the grid. The test spares the fast-forward of a ray that passes beside the
# grid almost parallel to a face: its entry crossing on that axis lies metres away, and adding
# up the other axes' crossings until then takes tens of thousands of steps (most of the time
# of a scan from some views, before this test).
_BESIDE = 1e-6


@numba.njit(cache=True, inline="always")
def _line_near_grid(ox, oy, oz, d0, d1, d2, resolution, first_key, n):
    """Whether the half-line origin + t * direction (t >= 0) passes within ``_BESIDE`` of the
    grid's cube."""
    low = first_key * resolution - _BESIDE
    high = (first_key + n) * resolution + _BESIDE
    return half_line_meets_box((np.float64(ox), np.float64(oy), np.float64(oz)),
                               (np.float64(d0), np.float64(d1), np.float64(d2)), (low, low, low), (high, high, high))


@numba.njit(cache=True)
def _skip_to_grid(k0, k1, k2, s0, s1, s2, t0, t1, t2, dt0, dt1, dt2, first_key, n):
    """Fast-forward the DDA to the step before it first enters the grid, with identical state.

    Each axis's crossing times are its own running sums (t += delta), so they can be advanced
    axis by axis; the DDA's interleaving only decides which crossing comes first, and the
    entry is the last of the axes' entry crossings in that order. Returns the new keys and
    pending times, the number of skipped steps (-1 if the ray never enters) and the entry time.
    """
    m0 = _keys_before_grid(k0, s0, first_key, n)
    m1 = _keys_before_grid(k1, s1, first_key, n)
    m2 = _keys_before_grid(k2, s2, first_key, n)
    if m0 < 0 or m1 < 0 or m2 < 0:
        return k0, k1, k2, t0, t1, t2, -1, 0.0
    # Pending time of each axis's entry crossing; the entry is the one the DDA takes last.
    entry_axis, entry_t = -1, -np.inf
    if m0 > 0:
        k0, t0 = _advance(k0, t0, s0, dt0, m0 - 1)
        entry_axis, entry_t = 0, t0
    if m1 > 0:
        k1, t1 = _advance(k1, t1, s1, dt1, m1 - 1)
        if t1 >= entry_t:
            entry_axis, entry_t = 1, t1
    if m2 > 0:
        k2, t2 = _advance(k2, t2, s2, dt2, m2 - 1)
        if t2 >= entry_t:
            entry_axis, entry_t = 2, t2
    skipped = (m0 - 1 if m0 > 0 else 0) + (m1 - 1 if m1 > 0 else 0) + (m2 - 1 if m2 > 0 else 0)
    if entry_axis != 0:
        k0, t0, c = _advance_before(k0, t0, s0, dt0, 0, entry_t, entry_axis)
        skipped += c
    if entry_axis != 1:
        k1, t1, c = _advance_before(k1, t1, s1, dt1, 1, entry_t, entry_axis)
        skipped += c
    if entry_axis != 2:
        k2, t2, c = _advance_before(k2, t2, s2, dt2, 2, entry_t, entry_axis)
        skipped += c
    if (_beyond_far_side(k0, s0, first_key, n) or _beyond_far_side(k1, s1, first_key, n)
            or _beyond_far_side(k2, s2, first_key, n)):
        return k0, k1, k2, t0, t1, t2, -1, entry_t  # passes beside the grid
    return k0, k1, k2, t0, t1, t2, skipped, entry_t


@numba.njit(cache=True, inline="always", error_model="numpy")
def _walk_start(ox, oy, oz, ex, ey, ez, resolution, first_key, free_mark):
    """Start OctoMap's computeRayKeys(origin, end): mark the origin voxel, set up the DDA and
    fast-forward it to the grid. Returns (active, keys, pending times, steps, deltas, end keys,
    length, was_inside)."""
    n = free_mark.shape[0]
    inv_resolution = 1.0 / resolution
    k0 = _coord_to_key(ox, inv_resolution)
    k1 = _coord_to_key(oy, inv_resolution)
    k2 = _coord_to_key(oz, inv_resolution)
    end0 = _coord_to_key(ex, inv_resolution)
    end1 = _coord_to_key(ey, inv_resolution)
    end2 = _coord_to_key(ez, inv_resolution)
    active = not (k0 == end0 and k1 == end1 and k2 == end2)
    was_inside = False
    if active:
        was_inside = _mark(free_mark, k0, k1, k2, first_key, n)

    d0, d1, d2 = ex - ox, ey - oy, ez - oz  # float32, as octomath::Vector3
    length = np.float32(math.sqrt(np.float64(d0 * d0 + d1 * d1 + d2 * d2)))
    d0, d1, d2 = d0 / length, d1 / length, d2 / length
    s0, t0, dt0 = _axis_setup(k0, ox, d0, resolution)
    s1, t1, dt1 = _axis_setup(k1, oy, d1, resolution)
    s2, t2, dt2 = _axis_setup(k2, oz, d2, resolution)
    length64 = np.float64(length)

    if active and not was_inside and _end_not_before_grid(end0, end1, end2, s0, s1, s2, first_key, n):
        if not _line_near_grid(ox, oy, oz, d0, d1, d2, resolution, first_key, n):
            active = False  # passes beside the grid
        else:
            k0, k1, k2, t0, t1, t2, skipped, entry_t = _skip_to_grid(
                k0, k1, k2, s0, s1, s2, t0, t1, t2, dt0, dt1, dt2, first_key, n)
            if skipped < 0 or (skipped > 0 and entry_t > length64):
                active = False  # never enters the grid, or ends before it
    return (active, k0, k1, k2, t0, t1, t2, s0, s1, s2, dt0, dt1, dt2, end0, end1, end2,
            length64, was_inside)


@numba.njit(cache=True, inline="always")
def _walk_step(k0, k1, k2, t0, t1, t2, s0, s1, s2, dt0, dt1, dt2, end0, end1, end2, length64,
               was_inside, first_key, free_mark):
    """One step of OctoMap's DDA; marks the new voxel free. Returns (active, keys, times, was_inside)."""
    # OctoMap's axis choice (smallest t; on ties the higher axis), written with selects
    # instead of branches: the choice is unpredictable, so branches would mispredict.
    c0 = (t0 < t1) & (t0 < t2)
    c1 = (t0 >= t1) & (t1 < t2)
    c2 = not (c0 or c1)
    k0 += s0 if c0 else 0
    k1 += s1 if c1 else 0
    k2 += s2 if c2 else 0
    t0 = t0 + dt0 if c0 else t0
    t1 = t1 + dt1 if c1 else t1
    t2 = t2 + dt2 if c2 else t2
    if k0 == end0 and k1 == end1 and k2 == end2:
        return False, k0, k1, k2, t0, t1, t2, was_inside
    if min(t0, min(t1, t2)) > length64:
        return False, k0, k1, k2, t0, t1, t2, was_inside
    inside = _mark(free_mark, k0, k1, k2, first_key, free_mark.shape[0])
    if was_inside and not inside:
        return False, k0, k1, k2, t0, t1, t2, was_inside  # left the cube: a ray cannot come back
    return True, k0, k1, k2, t0, t1, t2, was_inside or inside


@numba.njit(cache=True, inline="always", error_model="numpy")
def _free_walk_end(ox, oy, oz, px, py, pz, max_range, inv_resolution, first_key, occupied_mark):
    """OctoMap computeUpdate for one point: mark its voxel occupied when within range; return
    where the free-space walk ends (the point, or the point at max_range along the ray)."""
    dx, dy, dz = px - ox, py - oy, pz - oz
    distance = math.sqrt(np.float64(dx * dx + dy * dy + dz * dz))
    if max_range < 0.0 or distance <= max_range:
        _mark(occupied_mark, _coord_to_key(px, inv_resolution), _coord_to_key(py, inv_resolution),
              _coord_to_key(pz, inv_resolution), first_key, occupied_mark.shape[0])
        return px, py, pz
    length = np.float32(distance)
    reach = np.float32(max_range)
    return ox + (dx / length) * reach, oy + (dy / length) * reach, oz + (dz / length) * reach


# How far (metres) a ray's line may pass from the grid and be left out of the scan's update
# altogether. The walk follows the line from the sensor through the point up to float32
# rounding (about 1e-7 m here), so a ray whose line keeps farther away than this from the grid
# frees no voxel of it and ends outside it.
_NEAR_GRID = 1e-4


@numba.njit(cache=True)
def _rays_near_grid(origin, points, low, high):
    """(R,) int64 indices of the points whose ray from ``origin`` (the half-line through the
    point) meets the cube [low, high]^3."""
    start = (np.float64(origin[0]), np.float64(origin[1]), np.float64(origin[2]))
    near = np.empty(points.shape[0], dtype=np.int64)
    count = 0
    for i in range(points.shape[0]):
        direction = (np.float64(points[i, 0]) - start[0], np.float64(points[i, 1]) - start[1],
                     np.float64(points[i, 2]) - start[2])
        if half_line_meets_box(start, direction, (low, low, low), (high, high, high)):
            near[count] = i
            count += 1
    return near[:count]


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _mark_rays(origin, points, rays, max_range, resolution, first_key, free_mark, occupied_mark):
    """Mark the voxels a scan frees and occupies (OctoMap computeUpdate, before the hit-wins rule);
    ``rays`` indexes the points whose rays come near the grid (the others mark nothing).

    Rays are walked two at a time in one loop: each DDA step is a short chain of dependent
    operations, and interleaving two independent chains keeps the core busy.
    """
    inv_resolution = 1.0 / resolution
    ox, oy, oz = origin[0], origin[1], origin[2]
    count = rays.shape[0]
    for pair in numba.prange((count + 1) // 2):
        a, b = rays[2 * pair], rays[min(2 * pair + 1, count - 1)]  # an odd count walks the last ray twice
        ex, ey, ez = _free_walk_end(ox, oy, oz, points[a, 0], points[a, 1], points[a, 2], max_range,
                                    inv_resolution, first_key, occupied_mark)
        (on_a, a0, a1, a2, ta0, ta1, ta2, sa0, sa1, sa2, da0, da1, da2, ea0, ea1, ea2, la,
         ina) = _walk_start(ox, oy, oz, ex, ey, ez, resolution, first_key, free_mark)
        ex, ey, ez = _free_walk_end(ox, oy, oz, points[b, 0], points[b, 1], points[b, 2], max_range,
                                    inv_resolution, first_key, occupied_mark)
        (on_b, b0, b1, b2, tb0, tb1, tb2, sb0, sb1, sb2, db0, db1, db2, eb0, eb1, eb2, lb,
         inb) = _walk_start(ox, oy, oz, ex, ey, ez, resolution, first_key, free_mark)
        while on_a or on_b:
            if on_a:
                on_a, a0, a1, a2, ta0, ta1, ta2, ina = _walk_step(
                    a0, a1, a2, ta0, ta1, ta2, sa0, sa1, sa2, da0, da1, da2, ea0, ea1, ea2, la, ina,
                    first_key, free_mark)
            if on_b:
                on_b, b0, b1, b2, tb0, tb1, tb2, inb = _walk_step(
                    b0, b1, b2, tb0, tb1, tb2, sb0, sb1, sb2, db0, db1, db2, eb0, eb1, eb2, lb, inb,
                    first_key, free_mark)


@numba.njit(cache=True)
def _apply_update(log_odds, observed, voxels, update, clamp_min, clamp_max):
    """Add ``update`` to the flat log-odds of ``voxels`` and clamp, as OctoMap's updateNodeLogOdds."""
    for v in voxels:
        value = log_odds[v] + update
        if value < clamp_min:
            value = clamp_min
        elif value > clamp_max:
            value = clamp_max
        log_odds[v] = value
        observed[v] = True


# ---------------------------------------------------------------------------------------------
# Walking rays through a grid: the information-gain baseline


@numba.njit(cache=True, inline="always")
def _entropy(p):
    q = np.float64(p)
    return -(q * math.log(q) + (1.0 - q) * math.log(1.0 - q))


@numba.njit(cache=True, parallel=True, error_model="numpy")
def ray_information(origins, ends, probabilities, resolution, first_key, box_low, box_high, unknown_low,
                     unknown_high, scratch, information, first):
    """The information-gain walk (Kriegel et al. 2012, as the paper's baseline): every ray of every
    view (origins (V, 3), ends (V, N, 3) float32) walked with OctoMap's DDA (the voxels
    ``integrate`` would mark) until the first occupied voxel (p > 0.5) or its end.

    probabilities (n, n, n) float32; resolution, first_key: the grid's (voxel [i, j, k] has key
    first_key + i, ...); box_low <= i, j, k < box_high: the object's box in voxels; a voxel is
    unknown when unknown_low <= p <= unknown_high; scratch (n, n, n) bool, written (the walk's
    marks). Writes information[v, r] (V, N) float64: the entropy -p ln p - (1 - p) ln(1 - p) of the
    unknown box voxels the ray passes, and first[v, r] (V, N) int8: 1 when the first non-free box
    voxel it meets is occupied, 2 when it is unknown, 0 when it meets neither."""
    n = probabilities.shape[0]
    views, rays = ends.shape[0], ends.shape[1]
    for index in numba.prange(views * rays):
        v, r = index // rays, index % rays
        ox, oy, oz = origins[v, 0], origins[v, 1], origins[v, 2]
        (active, k0, k1, k2, t0, t1, t2, s0, s1, s2, dt0, dt1, dt2, e0, e1, e2, length,
         was_inside) = _walk_start(ox, oy, oz, ends[v, r, 0], ends[v, r, 1], ends[v, r, 2], resolution,
                                   first_key, scratch)
        total, met = 0.0, 0
        while active:
            active, k0, k1, k2, t0, t1, t2, was_inside = _walk_step(
                k0, k1, k2, t0, t1, t2, s0, s1, s2, dt0, dt1, dt2, e0, e1, e2, length, was_inside,
                first_key, scratch)
            i, j, k = k0 - first_key, k1 - first_key, k2 - first_key
            if not (active and 0 <= i < n and 0 <= j < n and 0 <= k < n):
                continue
            p = probabilities[i, j, k]
            in_box = box_low <= i < box_high and box_low <= j < box_high and box_low <= k < box_high
            if p > 0.5:
                if in_box and met == 0:
                    met = 1
                break
            if in_box and unknown_low <= p <= unknown_high:
                total += _entropy(p)
                if met == 0:
                    met = 2
        information[v, r] = total
        first[v, r] = met


@numba.njit(cache=True, error_model="numpy")
def ray_voxels(origins, ends, resolution, first_key, n):
    """The voxels of an n^3 grid that OctoMap's DDA passes on each ray, in walk order: the same walk
    as ``integrate`` and ``ray_information`` (``_walk_start``, ``_walk_step``), which depends on the
    geometry only, never on the grid's values, so it is made once per view set.

    origins (V, 3), ends (V, R, 3) float32: the rays (from each view's origin to its ray's end);
    resolution, first_key: the grid's (voxel [i, j, k] has key first_key + i, ...). Returns
    offsets (V * R + 1,) int64 and voxels (T,) int32: ray v * R + r passes the flat C-order voxels
    voxels[offsets[v * R + r]:offsets[v * R + r + 1]], the voxel holding its end excluded."""
    views, rays = ends.shape[0], ends.shape[1]
    scratch = np.zeros((n, n, n), dtype=np.uint8)
    offsets = np.zeros(views * rays + 1, dtype=np.int64)
    voxels = np.empty(views * rays * 3 * n, dtype=np.int32)  # a ray passes at most 3n - 2 voxels of the grid
    count = 0
    for index in range(views * rays):
        v, r = index // rays, index % rays
        (active, k0, k1, k2, t0, t1, t2, s0, s1, s2, dt0, dt1, dt2, e0, e1, e2, length,
         was_inside) = _walk_start(origins[v, 0], origins[v, 1], origins[v, 2], ends[v, r, 0], ends[v, r, 1],
                                   ends[v, r, 2], resolution, first_key, scratch)
        i, j, k = k0 - first_key, k1 - first_key, k2 - first_key
        if active and 0 <= i < n and 0 <= j < n and 0 <= k < n:  # the origin's own voxel
            voxels[count] = (i * n + j) * n + k
            count += 1
        while active:
            active, k0, k1, k2, t0, t1, t2, was_inside = _walk_step(
                k0, k1, k2, t0, t1, t2, s0, s1, s2, dt0, dt1, dt2, e0, e1, e2, length, was_inside, first_key,
                scratch)
            i, j, k = k0 - first_key, k1 - first_key, k2 - first_key
            if active and 0 <= i < n and 0 <= j < n and 0 <= k < n:
                voxels[count] = (i * n + j) * n + k
                count += 1
        offsets[index + 1] = count
    return offsets, voxels[:count]
