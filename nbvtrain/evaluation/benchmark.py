"""``nbvtrain benchmark``: the field's protocols on a corpus of real objects, built on the closed
loop of ``nbvtrain.evaluation.evaluate`` (the same planners, policies and reconstructions).

A protocol (``configs/protocols/NAME.yaml``, ``Protocol``) fixes settings only: the candidate
views (layout, reachability), the budgets (views scanned, the start included), the start rule,
the coverage thresholds and the fusion voxel (in radii of the object's bounding sphere: the
field's objects are normalised into the unit sphere), the targets of "scans to X %" and whether
an answer must be one of the candidate views. The scene, the oracle and the planners are today's.

Per reconstruction and scan (``coverage.csv``): surface coverage at the scene's own match
distance and of the observable surface, the path travelled (``nbvdata.core.paths``: round the
object's bounding sphere), and at each protocol threshold t the share of reference points within
t of a scanned point (``sc_t``) and that share over what every reachable view together reaches
(``nsc_t``). Per reconstruction and budget (``RUN_METRICS``): the AUC of the coverage curve
(PC-NBV's: the trapezoid over views 0..N with c0 = 0, divided by N), coverage, scans to each
target, path length in metres and in bounding-sphere radii, the Chamfer distance (ObjView-Bench's:
mean squared nearest-neighbour distance from the reference points to the scanned points and back,
the two summed, in radii squared, the scanned points fused in ``voxel`` voxels), the mean seconds
per decision, and the set-cover floor of the start (the fewest views that reach all the
observable surface). ``nbvtrain.evaluation.benchmark_report`` turns them into tables, statistics and plots.

The distances are those of each scan's noise-free points (a sensor with range noise is measured
on its noise-free twin): a candidate view's are computed once per mesh (``SurfaceMeasure``).
"""

from __future__ import annotations

import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Literal

import numpy as np
import yaml

from nbvdata.core.config import ConfigError, SimConfig, from_dict, load_config
from nbvdata.core.paths import path_lengths
from nbvdata.core.views import Pose
from nbvdata.simulation.episode import run_seed, scene_rng
from nbvdata.simulation.mesh import MeshError
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.sources import MeshSource
from nbvtrain.evaluation.evaluate import (evaluation_rng, front_view, limit_threads, mesh_cache, mesh_runner,
                                          reconstruct, recording_of, start_floor)
from nbvtrain.planners import Planner, SnappedPlanner

ROOT = Path(__file__).resolve().parents[2]  # the checkout: nbvtrain/evaluation/benchmark.py
PROTOCOLS = ROOT / "configs" / "protocols"
BENCH_MESHES = ROOT.parent / "shared" / "meshes" / "bench"
RUN_METRICS = ("auc", "coverage", "observable_coverage", "path_m", "path_radii", "chamfer", "seconds")
"""What ``benchmark`` records per reconstruction and budget, beside scans to each target and the
protocol's thresholds (``sc_T``, ``nsc_T``)."""


@dataclass(frozen=True)
class Protocol:
    """A benchmark protocol (module docstring); ``configs/protocols/*.yaml`` are instances."""

    name: str
    """What the protocol is called (``--protocol NAME``)."""
    source: str = ""
    """Where its definitions come from."""
    settings: tuple[str, ...] = ()
    """``section.key=value`` overrides of the simulation settings (the candidate views)."""
    budgets: dict = field(default_factory=lambda: {"10 scans": 10})
    """Label -> views scanned, the start view included (ObjView-Bench's K moves: K + 1)."""
    start: Literal["random", "front"] = "random"
    """Start views: "random" seeded random candidate views; "front" the view nearest +x first."""
    thresholds: tuple[float, ...] = ()
    """Coverage thresholds in bounding-sphere radii (none: the scene's ``coverage.threshold`` only)."""
    voxel: float = 0.005
    """Fusion voxel of the scanned points for the Chamfer distance, in bounding-sphere radii."""
    targets: tuple[float, ...] = (0.90, 0.95, 0.99)
    """Shares of the observable surface whose scans-to-reach are recorded."""
    snap: bool = False
    """Every answer becomes the nearest unscanned candidate view (``SnappedPlanner``)."""

    def __post_init__(self) -> None:
        where = f"protocol {self.name}"
        if not isinstance(self.budgets, dict) or not self.budgets or not all(
                isinstance(label, str) and isinstance(views, int) and not isinstance(views, bool) and views >= 1
                for label, views in self.budgets.items()):
            raise ConfigError(f"{where}: budgets={self.budgets!r}: give label: views scanned (an integer >= 1), e.g. "
                              "{\"10 scans\": 10}")
        if not all(t > 0 for t in self.thresholds) or not self.voxel > 0:
            raise ConfigError(f"{where}: thresholds and voxel must be > 0 (bounding-sphere radii)")
        if not all(0 < t <= 1 for t in self.targets):
            raise ConfigError(f"{where}: targets={list(self.targets)}: shares of the observable surface in (0, 1]")

    @property
    def views(self) -> int:
        """Views scanned per reconstruction: the largest budget."""
        return max(self.budgets.values())


def protocol_names() -> list[str]:
    """The protocols shipped in ``configs/protocols``."""
    return sorted(path.stem for path in PROTOCOLS.glob("*.yaml"))


def protocol_for(layout: str, count: int) -> str:
    """``benchmark``'s way to run on the views (``layout``, ``count``): the protocol that plays them
    (``--protocol scvp``), else a protocol file of one's own with those settings."""
    for name in protocol_names():
        settings = set(load_protocol(name).settings)
        if {f"views.layout={layout}", f"views.count={count}"} <= settings:
            return f"--protocol {name}"
    return f"give --protocol a file of your own with settings [views.layout={layout}, views.count={count}]"


def load_protocol(name: str | Path) -> Protocol:
    """``configs/protocols/NAME.yaml``, or a YAML file's path: ConfigError naming the known ones
    for another name, an unknown key (with a "did you mean") or a bad value."""
    path = Path(name)
    if path.suffix.lower() not in (".yaml", ".yml"):
        path = PROTOCOLS / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(f"--protocol {name}: no such protocol; choose from {', '.join(protocol_names())} "
                          f"({PROTOCOLS}), or give a protocol file (.yaml)")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise ConfigError(f"{path}: not valid YAML: {str(error).splitlines()[0]}") from None
    return from_dict(Protocol, data, "protocol")


def protocol_config(protocol: Protocol, config_file: Path | None = None, overrides: list[str] = ()) -> SimConfig:
    """The simulation settings of a benchmark: the defaults (or ``config_file``), the protocol's
    settings, then ``overrides`` (e.g. ``views.reach=hemi``)."""
    return load_config(SimConfig, config_file, [*protocol.settings, *overrides])


# ---------------------------------------------------------------------------------------------
# Measuring the scanned surface


@dataclass
class ScanDistances:
    """One scan against the mesh's reference points: ``to_points`` (R,) float32 distance from
    each reference point to the nearest scanned point (inf: none); the scanned points' (M, 3)
    float32 ``points``, their voxel ``keys`` (M,) int64, and (computed on first use, by
    ``SurfaceMeasure.to_reference``) their (M,) float64 squared distance to the nearest reference
    point."""

    to_points: np.ndarray
    points: np.ndarray
    keys: np.ndarray
    to_reference: np.ndarray | None = None


class SurfaceMeasure:
    """The distances a mesh's reconstructions are measured by, each candidate view's computed
    once (``scan``): reference points are ``scene.coverage.points``, distances in metres."""

    def __init__(self, scene: Scene, protocol: Protocol):
        from scipy.spatial import cKDTree

        self.scene = scene
        self.radius = scene.bounding_radius
        self.reference = np.asarray(scene.coverage.points, dtype=np.float64)
        self.tree = cKDTree(self.reference)
        self.voxel = protocol.voxel * self.radius
        self.thresholds = np.asarray(protocol.thresholds, dtype=np.float64) * self.radius
        self._views: dict[int, ScanDistances] = {}
        self._reachable: np.ndarray | None = None

    def view_of(self, pose: Pose) -> int | None:
        """The candidate view ``pose`` is, or None."""
        exact = np.flatnonzero((self.scene.views.positions == pose.position).all(axis=1))
        return int(exact[0]) if len(exact) else None

    def scan(self, pose: Pose) -> ScanDistances:
        """The distances of the noise-free scan from ``pose`` (a candidate view's: cached)."""
        view = self.view_of(pose)
        if view is not None and view in self._views:
            return self._views[view]
        distances = self._measure(self.scene.scanner.scan(pose, cloud=False).hit_points)
        if view is not None:
            self._views[view] = distances
        return distances

    def _measure(self, points: np.ndarray) -> ScanDistances:
        points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        if not len(points):
            return ScanDistances(np.full(len(self.reference), np.inf, dtype=np.float32), points,
                                 np.zeros(0, dtype=np.int64))
        return ScanDistances(_nearest(points, self.reference), points, voxel_keys(points, self.voxel))

    def to_reference(self, scan: ScanDistances) -> np.ndarray:
        """(M,) float64 squared distance from each of ``scan``'s points to the nearest reference point."""
        if scan.to_reference is None:
            scan.to_reference = self.tree.query(scan.points.astype(np.float64))[0] ** 2
        return scan.to_reference

    def reachable(self) -> np.ndarray:
        """(T, R) bool: the reference points within each threshold of some candidate view's scan
        (what every reachable view together reaches; ``nsc_t``'s denominator): every view cast
        in batches, each distance looked up only as far as the largest threshold."""
        if self._reachable is None:
            nearest = np.full(len(self.reference), np.inf, dtype=np.float32)
            bound = float(self.thresholds.max())
            for points in self.scene.scanner.iter_hit_points(self.scene.views):
                if len(points):
                    nearest = np.minimum(nearest, _nearest(points, self.reference, bound))
            self._reachable = nearest[None] < self.thresholds[:, None]
        return self._reachable


def _nearest(points: np.ndarray, reference: np.ndarray, bound: float = np.inf) -> np.ndarray:
    """(R,) float32 distance from each of ``reference`` (R, 3) to the nearest of ``points``
    (M, 3), inf beyond ``bound``."""
    from scipy.spatial import cKDTree

    tree = cKDTree(np.asarray(points, dtype=np.float64), balanced_tree=False, compact_nodes=False)
    return tree.query(reference, distance_upper_bound=bound)[0].astype(np.float32)


def voxel_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    """(M,) int64 one key per voxel of side ``voxel`` holding each point of ``points`` (M, 3)."""
    cells = np.floor(np.asarray(points, dtype=np.float64) / voxel).astype(np.int64) + (1 << 20)
    return (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]


class RunMeasure:
    """What one reconstruction has scanned, scan by scan (``add``), against ``measure``."""

    def __init__(self, measure: SurfaceMeasure):
        self.measure = measure
        self.nearest = np.full(len(measure.reference), np.inf, dtype=np.float32)
        self.scans: list[ScanDistances] = []
        self.views: set[int] = set()
        self.rows: list[dict] = []

    def add(self, scan: int, pose: Pose) -> None:
        distances = self.measure.scan(pose)
        self.nearest = np.minimum(self.nearest, distances.to_points)
        view = self.measure.view_of(pose)
        if view is None or view not in self.views:  # a view scanned again adds no point
            self.scans.append(distances)
        if view is not None:
            self.views.add(view)
        row = {}
        if len(self.measure.thresholds):
            reachable = self.measure.reachable()
            for t, limit, reach in zip(self.measure.thresholds / self.measure.radius, self.measure.thresholds,
                                       reachable):
                within = self.nearest < limit
                row[f"sc_{t:g}"] = float(within.mean())
                row[f"nsc_{t:g}"] = float((within & reach).sum() / max(reach.sum(), 1))
        self.rows.append(row)

    def chamfer(self) -> float:
        """The Chamfer distance of what was scanned so far, in bounding-sphere radii squared
        (module docstring): the points of the scans fused per voxel (their mean), both ways."""
        if not self.scans:
            return float("nan")
        keys = np.concatenate([scan.keys for scan in self.scans])
        unique, first, inverse, counts = np.unique(keys, return_index=True, return_inverse=True, return_counts=True)
        squared = np.concatenate([self.measure.to_reference(scan) for scan in self.scans])
        if (counts == 1).all():
            to_reference = squared
        else:  # voxels holding several points: their mean point
            points = np.concatenate([scan.points for scan in self.scans]).astype(np.float64)
            sums = np.zeros((len(unique), 3))
            np.add.at(sums, inverse, points)
            merged = counts > 1
            to_reference = squared[first].copy()
            to_reference[merged] = self.measure.tree.query(sums[merged] / counts[merged, None])[0] ** 2
        radius2 = self.measure.radius ** 2
        return float((self.nearest.astype(np.float64) ** 2).mean() / radius2 + to_reference.mean() / radius2)


# ---------------------------------------------------------------------------------------------
# Running a protocol


@dataclass
class MeshResult:
    """One mesh's ``coverage.csv`` rows, run summaries, floors, and why it failed (with where)."""

    rows: list[dict] = field(default_factory=list)
    runs: list[dict] = field(default_factory=list)
    floors: list[dict] = field(default_factory=list)
    failure: str | None = None
    trace: str | None = None


@dataclass
class BenchmarkReport:
    """Every mesh's results, in the order of the sources, and the failures (mesh file, reason)."""

    protocol: Protocol
    planners: list[str]
    rows: list[dict] = field(default_factory=list)
    runs: list[dict] = field(default_factory=list)
    floors: list[dict] = field(default_factory=list)
    failures: list[tuple[str, str]] = field(default_factory=list)
    tracebacks: list[tuple[str, str]] = field(default_factory=list)
    seconds: float = 0.0


def start_views_of(scene: Scene, mesh_id: str, protocol: Protocol, starts: int, seed: int) -> list[int]:
    """``starts`` distinct start views from the evaluation's stream of this mesh and seed (the
    first the front view with ``start`` "front")."""
    order = [int(view) for view in evaluation_rng(seed, mesh_id).permutation(len(scene.views))]
    if protocol.start == "front":
        front = front_view(scene)
        order = [front] + [view for view in order if view != front]
    return [order[k % len(order)] for k in range(starts)]


def benchmark_mesh(source: MeshSource, planners: list[Planner], config: SimConfig, protocol: Protocol,
                   starts: int, seed: int, rerun: Path | None = None, tick: Callable[[int], None] = lambda runs: None,
                   threads: int = 0) -> MeshResult:
    """Every planner from every start on one mesh (``MeshResult``); a mesh that fails to load, or on
    which a planner raises, gives no rows (every planner is compared on the same meshes)."""
    if threads:
        limit_threads(threads)
    result = MeshResult()
    try:
        obj = source.load(config.mesh)
        scene = Scene.build(obj, config, scene_rng(seed, source.mesh_id), threads)
    except (MeshError, ValueError, RuntimeError) as error:
        tick(len(planners) * starts)
        result.failure = str(error)
        return result
    measure = SurfaceMeasure(scene, protocol)
    cache = mesh_cache(scene, planners)
    firsts = start_views_of(scene, source.mesh_id, protocol, starts, seed)
    result.floors = [{"mesh": source.title, "start": number, "start_view": first}
                     | start_floor(scene, first, run_seed(seed, source.mesh_id, number))
                     for number, first in enumerate(firsts)]
    with recording_of(rerun, source.title) as recording:
        for index, planner in enumerate(planners):
            if protocol.snap and not isinstance(planner, SnappedPlanner):
                planner = SnappedPlanner(planner, scene.views)
            for number, first in enumerate(firsts):
                log = recording.run([planner.name, f"start_{number}"], scene) if recording is not None else None
                run = RunMeasure(measure)
                chamfers = {}

                def on_scan(scan: int, pose: Pose, run=run, chamfers=chamfers) -> None:
                    run.add(scan, pose)
                    if scan in protocol.budgets.values():
                        chamfers[scan] = run.chamfer()
                try:
                    rows = reconstruct(scene, planner, first, protocol.views, run_seed(seed, source.mesh_id, number),
                                       log, on_scan, cache)
                except ConfigError:
                    raise
                except Exception as error:  # a planner's bug: this mesh fails, the rest go on
                    tick((len(planners) - index) * len(firsts) - number)
                    return MeshResult(failure=f"planner {planner.name} raised {type(error).__name__} from start view "
                                              f"{first}: {error} (the mesh's rows are left out, so that every planner is "
                                              "compared on the same meshes; tracebacks.txt has where)",
                                      trace=traceback.format_exc())
                key = {"mesh": source.title, "planner": planner.name, "start": number, "start_view": first}
                path = path_lengths(np.array([[row["x"], row["y"], row["z"]] for row in rows]), measure.radius)
                for row, extra, travelled in zip(rows, run.rows, path):
                    result.rows.append(key | {"scan": row["scan"], "coverage": row["coverage"],
                                              "observable_coverage": row["observable_coverage"],
                                              "path_m": float(travelled), "seconds": row["seconds"],
                                              "x": row["x"], "y": row["y"], "z": row["z"]} | extra)
                for label, budget in protocol.budgets.items():
                    result.runs.append(key | {"budget": label} | run_metrics(rows[:budget], run.rows[:budget],
                                                                              path[:budget], measure.radius,
                                                                              chamfers[budget], protocol.targets))
                tick(1)
    return result


def auc(coverage: np.ndarray) -> float:
    """PC-NBV's area under the coverage curve of N views: the trapezoid over views 0..N with
    coverage 0 before the first, divided by N: (c1 + ... + c(N-1) + cN / 2) / N."""
    coverage = np.asarray(coverage, dtype=np.float64)
    if not len(coverage):
        return float("nan")
    return float((coverage[:-1].sum() + coverage[-1] / 2.0) / len(coverage))


def scans_to(observable: np.ndarray, target: float) -> int | None:
    """The first scan (1 = the start) whose observable coverage reaches ``target``, or None."""
    reached = np.flatnonzero(np.asarray(observable, dtype=np.float64) >= target - 1e-9)
    return int(reached[0]) + 1 if len(reached) else None


def run_metrics(rows: list[dict], extras: list[dict], path: np.ndarray, radius: float, chamfer: float,
                targets: tuple[float, ...]) -> dict:
    """One reconstruction's metrics over its first len(rows) scans (module docstring)."""
    coverage = np.array([row["coverage"] for row in rows])
    observable = np.array([row["observable_coverage"] for row in rows])
    decisions = [row["seconds"] for row in rows[1:]]
    metrics = {"auc": auc(coverage), "coverage": float(coverage[-1]), "observable_coverage": float(observable[-1]),
               "path_m": float(path[-1]), "path_radii": float(path[-1] / radius) if radius > 0 else float("nan"),
               "chamfer": chamfer, "seconds": float(np.mean(decisions)) if decisions else 0.0}
    for target in targets:
        reached = scans_to(observable, target)
        metrics[f"scans_to_{round(100 * target)}"] = reached
        metrics[f"path_to_{round(100 * target)}"] = None if reached is None else float(path[reached - 1])
    return metrics | (extras[-1] if extras else {})


def benchmark(sources: list[MeshSource], planners: list[Planner], config: SimConfig, protocol: Protocol,
              starts: int = 3, seed: int = 0, workers: int = 1, progress: bool = False,
              rerun: Path | None = None) -> BenchmarkReport:
    """Every planner from ``starts`` start views on every mesh under ``protocol`` (``config``: its
    settings applied, ``protocol_config``). ``workers`` > 1 runs meshes in that many processes; the
    results are the same, in the same order, as with one."""
    from tqdm import tqdm

    if starts < 1:
        raise ConfigError(f"--starts {starts}: at least one start view per object")
    began = time.perf_counter()
    report = BenchmarkReport(protocol, [planner.name for planner in planners])
    bar = tqdm(total=len(sources) * len(planners) * starts, unit="run", desc=f"benchmark {protocol.name}",
               disable=not progress, dynamic_ncols=True)
    if rerun is not None:
        from nbvdata.core.files import sweep_temporaries

        sweep_temporaries(Path(rerun))
    with mesh_runner(workers, bar) as run:
        results = run(benchmark_mesh, [(source, planners, config, protocol, starts, seed, rerun) for source in sources])
        for source, result in zip(sources, results):
            report.rows += result.rows
            report.runs += result.runs
            report.floors += result.floors
            name = str(source.path or source.name)
            if result.failure is not None:
                report.failures.append((name, result.failure.removeprefix(f"{name}: ")))
            if result.trace is not None:
                report.tracebacks.append((name, result.trace))
    bar.close()
    report.seconds = time.perf_counter() - began
    return report
