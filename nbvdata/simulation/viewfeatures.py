"""Per-view features: what each candidate view would look at in the grid, and where it lies
against the views already scanned - the input of a ranker that scores any view set, and the
field's hand-crafted volumetric metrics as columns of it.

``view_features(probabilities, scanned, bundle) -> (V, F) float32``, columns ``FEATURES``:

- **Ray statistics** over a coarse bundle of rays per view (``RayBundle``: ``width`` x
  ``height`` rays spread over the sensor's field of view, 16 x 12 by default, against the
  sensor's 176 x 144). Every ray is walked with OctoMap's DDA (the voxels ``integrate`` would
  pass; the walk is made once per view set, ``nbvdata.simulation.grid.ray_voxels``) from the view until the
  first occupied voxel or the grid's edge. A voxel is occupied when p > 0.5, unknown when never
  observed (p = 0.5 exactly), free otherwise; H(p) = -p ln p - (1 - p) ln(1 - p); the
  visibility of a voxel is the product of (1 - p) over the voxels before it on the ray.
  Per-ray means (sums / rays) unless said:

  ``grid_rays``        share of the rays that enter the grid
  ``occupied_first``   share whose first non-free voxel is occupied (surface seen before)
  ``unknown_first``    share whose first non-free voxel is unknown (a view of the unexplored)
  ``overlap``          occupied_first / (occupied_first + unknown_first): the overlap estimate
  ``unknown_passed``   unknown voxels passed before the first occupied one
  ``information``      their entropy (Kriegel et al. 2012: the ``infogain`` baseline's sum)
  ``occlusion_aware``  sum of visibility x H over every voxel passed, the occupied one included
                       (Delmerico et al. 2018's occlusion-aware information)
  ``unobserved_voxel`` the same over unknown voxels only (their unobserved-voxel information)
  ``rear_side_voxel``  share of rays whose first occupied voxel comes straight after an unknown
                       one: the back of a surface seen from the other side (their rear-side voxel)
  ``rear_side_entropy`` visibility x H of the run of unknown voxels straight before such a voxel
                       (their rear-side entropy)
  ``proximity_count``  sum over the unknown voxels passed of max(0, 5 - d), d their chessboard
                       distance in voxels to the nearest occupied voxel (their proximity count)
  ``near_unknown``     unknown voxels passed within 2 voxels of an occupied one
  ``average_entropy``  over the rays that meet an occupied voxel: their voxels' mean H (Kriegel
                       et al.'s average entropy; 0 when no ray meets one)
  ``area_factor``      Vasquez-Gomez et al. 2014's area factor of the view: each ray registers at
                       its first occupied voxel reached from a free one ("occupied") or its first
                       unknown voxel within 2 of an occupied one ("occplane"), else as unobserved;
                       f(occupied share; 0.2) + f(occplane share; 0.8), f(x; a) the smooth cubic
                       that is 0 at x = 0 and 1, and peaks at 1 at x = a
  ``depth``            voxels passed in the grid before the first non-free voxel, per ray that meets one
  ``proximity_shadow`` proximity count as ``rpg_ig_active_reconstruction`` implements it: the unknown
                       voxels passed, each weighted n - k where k is its distance in voxel steps behind
                       the first occupied voxel along a ray of a view scanned before (the minimum over
                       those rays; untagged voxels weigh 0): unknown space just behind surface already
                       measured, along the earlier scans' rays (``shadow_weights``, ``SHADOW_RAYS`` rays
                       per scanned view) - the scans' history, which a grid alone does not hold
  ``expected_surface`` the surface a ray can expect to newly see, given a surface prior P(surface) of
                       each unknown voxel (``surface``; 0 without one): 1 - prod (1 - P) over the unknown
                       voxels before the first occupied one

- **Relative to the state's best view** (the column / its largest value over the views, 0 when
  that is 0): ``unknown_first_rel``, ``information_rel``, ``proximity_rel``, ``rear_side_rel``;
  and of every hand-crafted metric, so that a ranker holds what each metric planner decides by
  (``METRIC_RELATIVE``): ``occlusion_aware_rel``, ``unobserved_voxel_rel``,
  ``rear_side_entropy_rel``, ``average_entropy_rel``, ``area_factor_rel``,
  ``proximity_shadow_rel``, ``expected_surface_rel``.
- **Camera history** (from the set of scanned positions, not their order): ``nearest_angle``,
  ``second_angle``, ``third_angle`` (radians to the nearest, second and third nearest scanned
  view; pi when there are fewer), ``within_30``, ``within_60`` (scanned views within 30 and 60
  degrees), ``mean_cosine`` (mean cosine to the scanned views; 0 with none).
- **The view itself**: ``elevation`` (the z of its unit direction), ``scans`` (views scanned so
  far), ``spacing`` (radians to its nearest other candidate view: how dense the view set is).
- **The whole grid**: ``grid_unknown``, ``grid_occupied`` (shares of the grid's voxels).

``FEATURE_GROUPS`` names the columns a ranker can be trained on in groups (``base``: the columns
of the first ranker; ``metrics``: the metrics relative to the state's best; ``shadow``; ``surface``).

Where ours differs from the sources (Delmerico et al.'s code, ``uzh-rpg/rpg_ig_active_reconstruction``):
unknown is "never observed" here (they take 0.2 <= p <= 0.8, which would call a voxel hit once,
p = 0.7, unknown); visibility multiplies (1 - p) as their paper defines it (their code multiplies
p); their proximity count and occplane use distances along the scan rays behind each hit (an
"occlusion shadow" kept in the tree), ours the distance to the nearest occupied voxel in the grid
alone, so that a grid is all the metric needs; every ray is cut at the grid's edge.

A quarter turn of the grid, the views and the scans about z leaves every feature unchanged (tested
on a 4-fold symmetric view set with an even bundle), but a view straight above's: its image keeps
world +x as its right (``nbvdata.core.views.look_at_rotations``), so its rays do not turn with the world.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy import ndimage

from nbvdata.core.config import GridConfig, SensorConfig
from nbvdata.core.views import ViewSet, look_at_rotations
from nbvdata.simulation.grid import ray_voxels
from nbvdata.simulation.sensor import camera_rays

RAY_COLUMNS = ("grid_rays", "occupied_first", "unknown_first", "overlap", "unknown_passed", "information",
               "occlusion_aware", "unobserved_voxel", "rear_side_voxel", "rear_side_entropy", "proximity_count",
               "near_unknown", "average_entropy", "area_factor", "depth")
RELATIVE_COLUMNS = ("unknown_first_rel", "information_rel", "proximity_rel", "rear_side_rel")
HISTORY_COLUMNS = ("nearest_angle", "second_angle", "third_angle", "within_30", "within_60", "mean_cosine")
VIEW_COLUMNS = ("elevation", "scans", "spacing")
GRID_COLUMNS = ("grid_unknown", "grid_occupied")
METRIC_RELATIVE = ("occlusion_aware_rel", "unobserved_voxel_rel", "rear_side_entropy_rel", "average_entropy_rel",
                   "area_factor_rel")
SHADOW_COLUMNS = ("proximity_shadow", "proximity_shadow_rel")
SURFACE_COLUMNS = ("expected_surface", "expected_surface_rel")
BASE = RAY_COLUMNS + RELATIVE_COLUMNS + HISTORY_COLUMNS + VIEW_COLUMNS + GRID_COLUMNS
FEATURES = BASE + METRIC_RELATIVE + SHADOW_COLUMNS + SURFACE_COLUMNS
"""The columns of ``view_features``, in order (module docstring)."""
FEATURE_GROUPS = {"base": BASE, "metrics": METRIC_RELATIVE, "shadow": SHADOW_COLUMNS, "surface": SURFACE_COLUMNS}
"""Columns by group, for a ranker trained on some of them (``base``: the first ranker's)."""

METRICS = {  # planner name -> the column it maximises
    "occlusion-aware": "occlusion_aware", "unobserved-voxel": "unobserved_voxel", "rear-side-voxel": "rear_side_voxel",
    "rear-side-entropy": "rear_side_entropy", "proximity-count": "proximity_count",
    "average-entropy": "average_entropy", "area-factor": "area_factor", "proximity-shadow": "proximity_shadow",
}
"""The hand-crafted metrics as planners: each takes the unscanned view with the highest value of its column."""

BUNDLE = (16, 12)
"""Default rays per view (width, height) of the coarse bundle: the ranker's features."""
METRIC_BUNDLE = (32, 24)
"""Rays per view of the hand-crafted metrics' planners: the sparse counts (rear side, proximity)
follow the sensor's full image more closely with more rays (``benchmarks/viewfeatures.py``), and
every metric of 500 views still takes under 20 ms on one core."""
PROXIMITY = 5
"""Proximity count's reach: unknown voxels d < 5 voxels from an occupied one count 5 - d."""
NEAR = 2
"""``near_unknown`` and the area factor's occplane: unknown voxels within this many voxels of an occupied one."""
AREA_DESIRED = (0.2, 0.8)
"""Vasquez-Gomez's desired shares of occupied and occplane rays (their code's defaults)."""
SHADOW_RAYS = (64, 48)
"""Rays per scanned view that tag the voxels behind its hits (``proximity_shadow``): about one ray
per voxel at the object, where their code casts every measured point's ray."""
_SHADOW_CACHE = 128  # scanned views whose dense walk a bundle keeps (a run scans tens)

# The sums the walk writes per view (``_view_sums``), in this order.
_SUMS = ("rays", "occupied_first", "unknown_first", "unknown_passed", "information", "occlusion_aware",
         "unobserved_voxel", "rear_side_voxel", "rear_side_entropy", "proximity_count", "near_unknown",
         "entropy_hit", "voxels_hit", "area_occupied", "area_occplane", "area_unobserved", "depth",
         "proximity_shadow", "expected_surface")


@dataclass(frozen=True)
class RayBundle:
    """The coarse rays of every candidate view, walked once through the grid's voxels.

    views : the candidate views (V)
    rays : R rays per view (``width`` x ``height``)
    offsets : (V * R + 1,) int64, voxels : (T,) int32 flat C-order voxel indices: ray v * R + r
        passes voxels[offsets[v * R + r]:offsets[v * R + r + 1]] in order (``nbvdata.simulation.grid.ray_voxels``)
    size : voxels per grid axis
    spacing : (V,) float64 radians from each view to its nearest other view
    grid, sensor : the scene's (the scanned views' dense walks, ``shadow_walk``, are made from them)
    """

    views: ViewSet
    rays: int
    offsets: np.ndarray
    voxels: np.ndarray
    size: int
    spacing: np.ndarray
    grid: GridConfig | None = None
    sensor: SensorConfig | None = None
    _walks: dict = dataclasses.field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def build(cls, views: ViewSet, grid: GridConfig, sensor: SensorConfig = SensorConfig(),
              width: int = BUNDLE[0], height: int = BUNDLE[1]) -> "RayBundle":
        """``width`` x ``height`` rays per view over the sensor's field of view (the pixel centres
        of an image that coarse), each from the view out to the sensor's far range; ``grid`` with
        its cube resolved (``SimConfig.scene_grid``)."""
        if width < 1 or height < 1:
            raise ValueError(f"a ray bundle of {width} x {height} rays: give at least 1 x 1")
        coarse = dataclasses.replace(sensor, width=width, height=height)
        directions = np.matmul(camera_rays(coarse)[None], views.rotations)  # (V, R, 3) world: R^T d
        origins = views.positions.astype(np.float32)
        ends = (views.positions[:, None] + directions * sensor.far).astype(np.float32)
        offsets, voxels = ray_voxels(origins, ends, grid.resolution, -(grid.size // 2), grid.size)
        units = views.unit_positions
        cosines = np.clip(units @ units.T, -1.0, 1.0)
        np.fill_diagonal(cosines, -1.0)
        spacing = np.arccos(cosines.max(axis=1)) if len(units) > 1 else np.full(len(units), np.pi)
        return cls(views, width * height, offsets, voxels, grid.size, spacing, grid, sensor)

    def shadow_walk(self, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(offsets, voxels) of ``SHADOW_RAYS`` rays of a sensor scanned at ``position`` (3,),
        looking at the centre (a view of the bundle or any other), made once and kept."""
        key = np.asarray(position, dtype=np.float64).tobytes()
        walk = self._walks.get(key)
        if walk is None:
            if self.grid is None or self.sensor is None:
                raise ValueError("a RayBundle made without its grid and sensor: make it with RayBundle.build")
            position = np.asarray(position, dtype=np.float64)[None]
            one = ViewSet(position, look_at_rotations(position))
            dense = RayBundle.build(one, self.grid, self.sensor, *SHADOW_RAYS)
            if len(self._walks) >= _SHADOW_CACHE:
                self._walks.pop(next(iter(self._walks)))
            walk = self._walks[key] = (dense.offsets, dense.voxels)
        return walk


def occupied_distance(probabilities: np.ndarray, reach: int = PROXIMITY) -> np.ndarray:
    """(n^3,) int8: each voxel's chessboard distance in voxels to the nearest occupied voxel
    (p > 0.5; 0 for an occupied voxel), capped at ``reach`` (also with no occupied voxel)."""
    occupied = np.asarray(probabilities) > 0.5
    if not occupied.any():
        return np.full(occupied.size, reach, dtype=np.int8)
    distance = ndimage.distance_transform_cdt(~occupied, metric="chessboard")
    return np.minimum(distance, reach).astype(np.int8).reshape(-1)


def shadow_weights(probabilities: np.ndarray, scanned: np.ndarray, bundle: RayBundle) -> np.ndarray:
    """(n^3,) float64: each unknown voxel's ``proximity_shadow`` weight, n - k for the fewest voxel
    steps k it lies behind the first occupied voxel along a ray of a scan from ``scanned`` (P, 3)
    (``SHADOW_RAYS`` rays per scan, ``RayBundle.shadow_walk``), 0 where no such ray passes it."""
    flat = np.ascontiguousarray(probabilities, dtype=np.float32).reshape(-1)
    n = bundle.size
    tags = np.full(flat.size, n, dtype=np.int32)
    for position in np.asarray(scanned, dtype=np.float64).reshape(-1, 3):
        offsets, voxels = bundle.shadow_walk(position)
        _shadow_tags(flat, offsets, voxels, tags)
    return np.where(flat == 0.5, (n - tags).astype(np.float64), 0.0)


def view_sums(probabilities: np.ndarray, bundle: RayBundle, scanned: np.ndarray | None = None,
              surface: np.ndarray | None = None, shadow: np.ndarray | None = None) -> np.ndarray:
    """(V, len(_SUMS)) float64: the walk's sums per view for a (n, n, n) grid (module docstring);
    ``scanned`` (P, 3): the scans' positions (``proximity_shadow``; None: none), ``surface`` (n, n, n)
    a prior's P(surface) of each voxel (``expected_surface``; None: 0); ``shadow``: the scans'
    ``shadow_weights`` where the caller has them already."""
    probabilities = np.ascontiguousarray(probabilities, dtype=np.float32)
    if probabilities.shape != (bundle.size,) * 3:
        raise ValueError(f"a grid of shape {probabilities.shape}; the ray bundle was made for {(bundle.size,) * 3}")
    flat = probabilities.reshape(-1)
    sums = np.zeros((len(bundle.views), len(_SUMS)))
    if shadow is None:
        shadow = shadow_weights(probabilities, scanned, bundle) if scanned is not None and len(scanned) else \
            np.zeros(flat.size)
    prior = np.zeros(flat.size) if surface is None else np.ascontiguousarray(surface, dtype=np.float64).reshape(-1)
    _view_sums(flat, _entropies(flat), occupied_distance(probabilities), shadow, prior, bundle.offsets,
               bundle.voxels, bundle.rays, PROXIMITY, NEAR, sums)
    return sums


def view_features(probabilities: np.ndarray, scanned: np.ndarray, bundle: RayBundle,
                  surface: np.ndarray | None = None, shadow: np.ndarray | None = None) -> np.ndarray:
    """(V, F) float32, the columns ``FEATURES``, of every view of ``bundle`` at the state of the
    (n, n, n) grid ``probabilities`` (authors' encoding, 0.5 = unknown) after scans from the
    positions ``scanned`` (P, 3) (object-centred, any radius, any order; P may be 0); ``surface``
    (n, n, n): a surface prior's P(surface) per voxel, for ``expected_surface`` (None: 0);
    ``shadow``: the scans' ``shadow_weights`` where the caller has them already."""
    sums = view_sums(probabilities, bundle, scanned, surface, shadow)
    columns = dict(zip(_SUMS, sums.T))
    rays = float(bundle.rays)
    met = columns["occupied_first"] + columns["unknown_first"]
    out = {"grid_rays": columns["rays"] / rays, "occupied_first": columns["occupied_first"] / rays,
           "unknown_first": columns["unknown_first"] / rays,
           "overlap": _ratio(columns["occupied_first"], met)}
    for name in ("unknown_passed", "information", "occlusion_aware", "unobserved_voxel", "rear_side_voxel",
                 "rear_side_entropy", "proximity_count", "near_unknown", "proximity_shadow", "expected_surface"):
        out[name] = columns[name] / rays
    out["average_entropy"] = _ratio(columns["entropy_hit"], columns["voxels_hit"])
    registered = columns["area_occupied"] + columns["area_occplane"] + columns["area_unobserved"]
    out["area_factor"] = (area_factor(_ratio(columns["area_occupied"], registered), AREA_DESIRED[0])
                          + area_factor(_ratio(columns["area_occplane"], registered), AREA_DESIRED[1]))
    out["depth"] = _ratio(columns["depth"], met)
    relatives = dict(zip(RELATIVE_COLUMNS, ("unknown_first", "information", "proximity_count", "rear_side_voxel")))
    relatives |= {name: name.removesuffix("_rel") for name in METRIC_RELATIVE + SHADOW_COLUMNS[1:] + SURFACE_COLUMNS[1:]}
    for relative, name in relatives.items():
        best = out[name].max() if len(out[name]) else 0.0
        out[relative] = out[name] / best if best > 0 else np.zeros_like(out[name])
    out |= camera_history(bundle.views.unit_positions, scanned)
    units = bundle.views.unit_positions
    out["elevation"] = units[:, 2]
    out["scans"] = np.full(len(units), float(len(np.asarray(scanned).reshape(-1, 3))))
    out["spacing"] = bundle.spacing
    grid = np.asarray(probabilities)
    out["grid_unknown"] = np.full(len(units), float((grid == 0.5).mean()))
    out["grid_occupied"] = np.full(len(units), float((grid > 0.5).mean()))
    return np.stack([np.asarray(out[name], dtype=np.float64) for name in FEATURES], axis=1).astype(np.float32)


def camera_history(units: np.ndarray, scanned: np.ndarray) -> dict[str, np.ndarray]:
    """The history columns (``HISTORY_COLUMNS``) of views ``units`` (V, 3) unit directions against
    the scanned positions ``scanned`` (P, 3): each (V,) float64. Cosines summed term by term (no
    BLAS), so the same on every CPU."""
    units = np.asarray(units, dtype=np.float64)
    scanned = np.asarray(scanned, dtype=np.float64).reshape(-1, 3)
    if not len(scanned):
        far = np.full(len(units), np.pi)
        zero = np.zeros(len(units))
        return {"nearest_angle": far, "second_angle": far.copy(), "third_angle": far.copy(), "within_30": zero,
                "within_60": zero.copy(), "mean_cosine": zero.copy()}
    norms = np.sqrt(scanned[:, 0] ** 2 + scanned[:, 1] ** 2 + scanned[:, 2] ** 2)
    directions = scanned / np.where(norms > 0, norms, 1.0)[:, None]
    cosines = np.stack([units[:, 0] * d[0] + units[:, 1] * d[1] + units[:, 2] * d[2] for d in directions], axis=1)
    cosines = np.clip(cosines, -1.0, 1.0)
    nearest = -np.sort(-cosines, axis=1)  # (V, P) largest cosine first
    angles = [np.arccos(nearest[:, k]) if nearest.shape[1] > k else np.full(len(units), np.pi) for k in range(3)]
    return {"nearest_angle": angles[0], "second_angle": angles[1], "third_angle": angles[2],
            "within_30": (cosines >= math.cos(math.radians(30))).sum(axis=1).astype(np.float64),
            "within_60": (cosines >= math.cos(math.radians(60))).sum(axis=1).astype(np.float64),
            "mean_cosine": cosines.mean(axis=1)}


def area_factor(share: np.ndarray, desired: float) -> np.ndarray:
    """Vasquez-Gomez et al.'s area factor of a share x in [0, 1] with desired share a: -2/a^3 x^3 +
    3/a^2 x^2 up to a, then the cubic through (a, 1) and (1, 0) with zero slope at both."""
    x = np.asarray(share, dtype=np.float64)
    a = float(desired)
    m = (a - 1.0) ** 3
    low = -2.0 / a ** 3 * x ** 3 + 3.0 / a ** 2 * x ** 2
    high = (-2.0 * x ** 3 + (3.0 * a + 3.0) * x ** 2 - 6.0 * a * x + (3.0 * a - 1.0)) / m
    return np.where(x <= a, low, high)


def _ratio(numerator: np.ndarray, denominator: np.ndarray) -> np.ndarray:
    return np.divide(numerator, denominator, out=np.zeros(len(numerator)), where=denominator > 0)


@numba.njit(cache=True, inline="always")
def _entropy(p):
    q = np.float64(p)
    if q <= 0.0 or q >= 1.0:
        return 0.0
    return -(q * math.log(q) + (1.0 - q) * math.log(1.0 - q))


@numba.njit(cache=True)
def _entropies(probabilities):
    """(n^3,) float64 H(p) of every voxel of the flat grid ``probabilities`` (n^3,) float32."""
    out = np.empty(probabilities.shape[0])
    for i in range(probabilities.shape[0]):
        out[i] = _entropy(probabilities[i])
    return out


@numba.njit(cache=True)
def _shadow_tags(probabilities, offsets, voxels, tags):
    """For every ray of a walk (``offsets``, ``voxels``), lower ``tags`` (n^3,) int32 of each voxel
    k steps behind the ray's first occupied voxel to k where that is fewer (unknown voxels only
    are read later; the ray goes on through everything behind the hit, as a measured ray extended)."""
    for ray in range(len(offsets) - 1):
        behind = -1
        for index in range(offsets[ray], offsets[ray + 1]):
            voxel = voxels[index]
            if behind < 0:
                if probabilities[voxel] > 0.5:
                    behind = 0
                continue
            behind += 1
            if probabilities[voxel] == 0.5 and behind < tags[voxel]:
                tags[voxel] = behind


@numba.njit(cache=True)
def _view_sums(probabilities, entropies, distance, shadow, surface, offsets, voxels, rays, reach, near, sums):
    """Walk every ray of every view (module docstring) over the flat grid ``probabilities`` (n^3,)
    float32 with its voxels' ``entropies`` (n^3,) float64, ``distance`` (n^3,) int8 to the
    nearest occupied voxel, ``shadow`` (n^3,) float64 weights and ``surface`` (n^3,) float64
    P(surface); add each ray's values to
    its view's row of ``sums`` (V, len(_SUMS)) float64, in ray order (the same sums everywhere)."""
    views = sums.shape[0]
    for v in range(views):
        for r in range(rays):
            ray = v * rays + r
            start, stop = offsets[ray], offsets[ray + 1]
            if stop == start:
                continue
            sums[v, 0] += 1.0
            visibility = 1.0
            first = 0  # 1: the first non-free voxel is occupied, 2: unknown
            passed, information, aware, unobserved = 0.0, 0.0, 0.0, 0.0
            run_entropy, entropy_sum, count = 0.0, 0.0, 0.0
            proximity, near_count, depth = 0.0, 0.0, 0.0
            behind, unseen = 0.0, 1.0  # the shadow's weights passed; the chance no surface is met yet
            previous_unknown, previous_free = False, True  # nothing before the grid: free
            registered = 0  # area factor: 1 occupied, 2 occplane
            hit = False
            for index in range(start, stop):
                voxel = voxels[index]
                p = probabilities[voxel]
                h = entropies[voxel]
                if p > 0.5:  # occupied: the ray ends here
                    if first == 0:
                        first = 1
                    aware += visibility * h
                    entropy_sum += h
                    count += 1.0
                    if previous_unknown:
                        sums[v, 7] += 1.0
                        sums[v, 8] += run_entropy
                    if registered == 0 and previous_free:
                        registered = 1
                    hit = True
                    break
                entropy_sum += h
                count += 1.0
                aware += visibility * h
                if p == 0.5:  # unknown
                    if first == 0:
                        first = 2
                    d = distance[voxel]
                    passed += 1.0
                    information += h
                    unobserved += visibility * h
                    run_entropy += visibility * h
                    if d < reach:
                        proximity += reach - d
                    behind += shadow[voxel]
                    unseen *= 1.0 - surface[voxel]
                    if d <= near:
                        near_count += 1.0
                        if registered == 0:
                            registered = 2
                    previous_unknown, previous_free = True, False
                else:  # free
                    if first == 0:
                        depth += 1.0
                    run_entropy = 0.0
                    previous_unknown, previous_free = False, True
                visibility *= 1.0 - np.float64(p)
            if first == 1:
                sums[v, 1] += 1.0
            elif first == 2:
                sums[v, 2] += 1.0
            if first != 0:
                sums[v, 16] += depth
            sums[v, 3] += passed
            sums[v, 4] += information
            sums[v, 5] += aware
            sums[v, 6] += unobserved
            sums[v, 9] += proximity
            sums[v, 10] += near_count
            sums[v, 17] += behind
            sums[v, 18] += 1.0 - unseen
            if hit:
                sums[v, 11] += entropy_sum
                sums[v, 12] += count
            if registered == 1:
                sums[v, 13] += 1.0
            elif registered == 2:
                sums[v, 14] += 1.0
            else:
                sums[v, 15] += 1.0
