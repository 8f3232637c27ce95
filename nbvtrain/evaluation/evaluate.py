"""Closed-loop reconstructions of unseen objects, one per (mesh, planner, start): ``nbvtrain evaluate``.

Every planner drives the same simulator as ``nbvdata generate`` (``nbvdata.simulation.episode.Reconstruction``,
scans cast live so continuous poses work): scan from the start view, then ``scans - 1`` times
ask the planner for the next pose, scan there and integrate. Start 0 is the candidate view in
front of the object (nearest to +x, as the paper starts), starts 1..K are seeded random
candidate views (``--random-starts K``: K + 1 starts in all; ``nbvtrain benchmark --starts N``
counts all N), the same for every planner, drawn from the evaluation's own stream
(``evaluation_rng``), never the front view nor one of the start views of the ``episode.runs_per_mesh`` runs
``nbvdata generate`` makes of that mesh with the same seed (``nbvdata.simulation.episode.start_view``), so
evaluating on a training mesh does not begin at a training sample. Each reconstruction's seed
is split (``SeedSequence.spawn``) into one stream for the sensor's range noise and one for the
planner (the random planner's choices), so neither depends on the other.

The overlap of a chosen pose is measured as the oracle's (``nbvdata.simulation.oracle``), on what its scan
actually covered: with S the reference points the live scan from the pose covers and C those
covered before it, overlap = |S & C| / |S| (0 when S is empty); for a candidate view with a
noise-free sensor S = O_v, the oracle's own overlap(v). A choice breaks the overlap rule when
this is below ``oracle.min_overlap``. The oracle breaks it only when no candidate view passes
(it then takes the most informative one); information gain judges the rule by an estimate from
the grid (and falls back likewise), so it can break it; the other planners never check it.

Outputs in the folder ``out``:

    coverage.csv   one row per (mesh, planner, start, scan): coverage of all reference points and
                   of the observable ones (seen from some candidate view), seconds the planner
                   took to choose that scan's pose (0 for the start), the pose, the pose's overlap
                   and how many candidate views were valid before it (both empty for the start)
    summary.md     coverage after the last scan (objects x planners, best and tied best in bold,
                   mean row, the paper's Table 1 figures where an object matches), scans to reach
                   90 / 95 / 99 % of the observable surface beside the floor, time per NBV, and
                   how often each planner broke the overlap rule
    floors.csv     one row per (mesh, start): the set cover of what the start scan left
                   (``nbvdata.simulation.setcover``): its size, proven bound and the greedy cover's size;
                   1 + size is the fewest scans that reach all the observable surface from that
                   start, the floor no planner can beat
    plots/*.png    coverage against scans per object, like the paper's Figs. 8-10, with the
                   floor marked
    config.yaml    the simulation settings and the evaluation's arguments (with ``--manifest``: the
                   version's name, version, manifest sha256 and path, and the part evaluated)
    failures.tsv   meshes that could not be used: a ``mesh<TAB>reason`` header, then one row each
                   (only when there are some)
    tracebacks.txt where a planner raised (a user's policy, say): each mesh's Python traceback
                   (only when there are some)

When every mesh failed there is nothing to compare: summary.md says so and lists the failures,
and no plots are drawn.
"""

from __future__ import annotations

import contextlib
import csv
import threading
import time
import traceback
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator

import numpy as np
import yaml

from nbvdata.core.config import ConfigError, SimConfig, to_dict
from nbvdata.simulation.episode import Reconstruction, ViewCache, mesh_stream, run_seed, scene_rng, start_view
from nbvdata.simulation.mesh import MeshError
from nbvdata.simulation.oracle import overlap, popcount
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.sources import MeshSource
from nbvtrain.planners import Observation, Planner

if TYPE_CHECKING:
    from nbvdata.core.views import Pose
    from nbvdata.view.rerun import RunLog

FRONT = np.array([1.0, 0.0, 0.0])
CSV_COLUMNS = ("mesh", "planner", "start", "start_view", "scan", "coverage", "observable_coverage", "seconds",
               "x", "y", "z", "overlap", "valid_views")
FLOOR_COLUMNS = ("mesh", "start", "start_view", "cover_size", "cover_bound", "cover_greedy")
TARGETS = (0.90, 0.95, 0.99)  # shares of the observable surface for the scans-to-X table
# Spawn key of the evaluation's start views; nbvdata.simulation.episode's per-mesh streams use 0 (reference
# points), 1 (generation start views) and 2 (generation runs).
EVALUATION_STREAM = 3
# The paper's Table 1: coverage (%) after 10 scans, and time per NBV (s), GTX 1080.
PAPER_COVERAGE = {  # object keyword: (classification, regression, information gain)
    "sphere": (96.7, 95.7, 96.2), "mask": (94.7, 95.3, 95.0), "helmet": (82.7, 84.9, 86.5),
    "sarcophagus": (64.2, 71.7, 94.1), "bunny": (90.0, 97.8, 98.1), "dragon": (71.3, 85.4, 90.4),
    "teapot": (87.1, 93.0, 93.2), "caster": (89.1, 90.6, 100.0), "moai": (96.8, 97.1, 98.9),
    "valve": (73.3, 70.7, 85.9), "armadillo": (84.6, 86.0, 95.2), "chair": (85.2, 84.6, 89.4),
    "hammer": (53.2, 56.8, 57.0),
}
PAPER_SECONDS = {"classification": 0.01, "regression": 0.3, "infogain": 29.9}


@dataclass
class EvaluationReport:
    """rows: the coverage.csv rows; failures: (mesh file, reason); seconds: wall time;
    min_overlap: the overlap rule the rows' overlaps are judged by."""

    rows: list[dict] = field(default_factory=list)
    failures: list[tuple[str, str]] = field(default_factory=list)
    tracebacks: list[tuple[str, str]] = field(default_factory=list)  # (mesh file, traceback) where a planner raised
    seconds: float = 0.0
    min_overlap: float = SimConfig().oracle.min_overlap
    floors: list[dict] = field(default_factory=list)  # the floors.csv rows


def front_view(scene: Scene) -> int:
    """The candidate view nearest to the front of the object (+x)."""
    return int(np.argmax(scene.views.unit_positions @ FRONT))


def evaluation_rng(seed: int, mesh_id: str) -> np.random.Generator:
    """The evaluation's own stream for a mesh: ``nbvdata.simulation.episode.mesh_stream`` with spawn key
    ``EVALUATION_STREAM``, which no generation stream uses."""
    return np.random.default_rng(mesh_stream(seed, mesh_id, EVALUATION_STREAM))


def start_views(scene: Scene, mesh_id: str, random_starts: int, seed: int, generation_runs: int) -> list[int]:
    """Start 0 in front, then ``random_starts`` random candidate views from ``evaluation_rng`` (distinct
    while they last), leaving out the front view and the start views of generation runs
    0..``generation_runs``-1 of this mesh and seed (unless that leaves none)."""
    count, front = len(scene.views), front_view(scene)
    taken = {front} | {start_view(seed, mesh_id, count, run) for run in range(min(generation_runs, count))}
    order = evaluation_rng(seed, mesh_id).permutation(count)
    free = [int(view) for view in order if view not in taken] or [int(view) for view in order]
    return [front] + [free[k % len(free)] for k in range(random_starts)]


def start_floor(scene: Scene, first_view: int, seed: int) -> dict:
    """The set cover of what the start scan from ``first_view`` left (the scan as ``reconstruct``
    casts it with the reconstruction seed ``seed``): cover_size, cover_bound, cover_greedy."""
    noise, _ = np.random.SeedSequence(seed).spawn(2)
    state = Reconstruction(scene, None, np.random.default_rng(noise))
    state.scan_pose(scene.views[first_view])
    cover = scene.plan_cover(state.covered)
    return {"cover_size": cover.size, "cover_bound": cover.bound, "cover_greedy": cover.greedy}


def reconstruct(scene: Scene, planner: Planner, first_view: int, scans: int, seed: int,
                log: RunLog | None = None, on_scan: Callable[[int, Pose], None] | None = None,
                cache: ViewCache | None = None) -> list[dict]:
    """One closed-loop reconstruction: (scans) rows of scan, coverage, observable_coverage,
    seconds, the pose position, its overlap and the number of valid candidate views before it
    (None for the start). Only a privileged planner sees the ``Reconstruction``; one that reads
    points gets every point scanned so far (``nbvdata.core.cloud``, kept as the generator keeps them).
    ``log``: also record every state, with the oracle's scores and the planner's next pose, in a
    Rerun recording (``nbvdata.view.rerun``; it changes no row). ``on_scan(scan, pose)``: called after
    each scan (``nbvtrain.evaluation.benchmark`` measures the scanned points there; it changes no row).
    ``cache``: the mesh's ``ViewCache`` (noise-free sensor only; made with points when the
    planner reads them): a pose that is a candidate view takes its cached grid update and covered
    points, the same as casting it live (tested), once per mesh instead of once per scan."""
    noise, choices = np.random.SeedSequence(seed).spawn(2)
    planner.start(choices)
    state = Reconstruction(scene, cache, np.random.default_rng(noise), points=planner.reads_points)
    min_overlap = scene.config.oracle.min_overlap
    pose, seconds, pose_overlap, valid_views = scene.views[first_view], 0.0, None, None
    poses, rows = [], []
    for scan in range(1, scans + 1):
        if scan > 1:
            observation = Observation(state.grid.probabilities(), tuple(poses),
                                      state.cloud.points() if state.cloud is not None else None)
            started = time.perf_counter()
            pose = planner.next_pose(observation, state if planner.privileged else None)
            seconds = time.perf_counter() - started
            scores = scene.oracle.score(state.covered)
            valid_views = int(((scores.overlaps >= min_overlap) & (scores.new > 0)).sum())
            if log is not None:  # the state the planner chose from
                log.scored_step(scan - 1, state.grid.probabilities(), poses[-1], state.covered, pose)
        before = state.covered.copy()
        view = _candidate_view(scene, pose) if cache is not None else None
        seen = state.scan(view) if view is not None else state.scan_pose(pose)
        if scan > 1:
            pose_overlap = overlap(seen, before)
        poses.append(pose)
        if on_scan is not None:
            on_scan(scan, pose)
        x, y, z = pose.position.tolist()
        rows.append({"scan": scan, "coverage": popcount(state.covered) / scene.oracle.points,
                     "observable_coverage": scene.oracle.observable_coverage(state.covered),
                     "seconds": seconds, "x": x, "y": y, "z": z, "overlap": pose_overlap,
                     "valid_views": valid_views})
    if log is not None:
        log.scored_step(scans, state.grid.probabilities(), poses[-1], state.covered)
    return rows


def _candidate_view(scene: Scene, pose: Pose) -> int | None:
    """The candidate view whose pose ``pose`` is (the same position), or None."""
    exact = np.flatnonzero((scene.views.positions == pose.position).all(axis=1))
    return int(exact[0]) if len(exact) else None


def mesh_cache(scene: Scene, planners: list[Planner]) -> ViewCache | None:
    """The ``ViewCache`` a mesh's reconstructions share: None with a noisy sensor (every scan live)."""
    if scene.config.sensor.noise_std > 0:
        return None
    return ViewCache(scene, any(planner.reads_points for planner in planners))


def evaluate(sources: list[MeshSource], planners: list[Planner], config: SimConfig, scans: int = 10,
             random_starts: int = 0, seed: int = 0, progress: bool = False, workers: int = 1,
             floors: bool = True, rerun: Path | None = None) -> EvaluationReport:
    """Reconstruct every mesh with every planner from 1 + ``random_starts`` start views (``write_outputs``
    then writes the files). ``workers`` > 1 evaluates meshes in that many processes (joblib loky,
    one thread each); the rows are the same, in the same order, as with one. ``floors`` False
    leaves out the set cover of every start (``start_floor``: up to ``oracle.cover_node_limit``
    branch-and-bound nodes each), e.g. for the many evaluations that choose a network. ``rerun``: a folder for
    one Rerun recording per mesh, ``<mesh>.rrd`` (``evaluate_mesh``); the rows are the same."""
    from tqdm import tqdm

    began = time.perf_counter()
    report = EvaluationReport(min_overlap=config.oracle.min_overlap)
    bar = tqdm(total=len(sources) * len(planners) * (1 + random_starts), unit="run", desc="evaluate",
               disable=not progress, dynamic_ncols=True)
    if rerun is not None:  # recordings a killed evaluation left half-written
        from nbvdata.core.files import sweep_temporaries

        sweep_temporaries(Path(rerun))
    with mesh_runner(workers, bar) as run:
        results = run(evaluate_mesh, [(source, planners, config, scans, random_starts, seed, floors, rerun)
                                      for source in sources])
        for source, (rows, floors, failure, trace) in zip(sources, results):
            report.rows += rows
            report.floors += floors
            name = str(source.path or source.name)
            if failure is not None:
                report.failures.append((name, failure.removeprefix(f"{name}: ")))  # the caller prints them
            if trace is not None:
                report.tracebacks.append((name, trace))
    bar.close()
    report.seconds = time.perf_counter() - began
    return report


def evaluate_mesh(source: MeshSource, planners: list[Planner], config: SimConfig, scans: int, random_starts: int,
                  seed: int, floors: bool = True, rerun: Path | None = None,
                  tick: Callable[[int], None] = lambda runs: None,
                  threads: int = 0) -> tuple[list[dict], list[dict], str | None, str | None]:
    """One mesh's coverage.csv rows (planner by planner, start by start), its floors.csv rows (one
    per start; none without ``floors``), why it could not be used (None if it could: a mesh that
    fails to load, or on which a planner raises, gives no rows) and the planner's traceback (None
    unless one raised). ``tick(runs)`` counts
    reconstructions; ``threads`` > 0 limits numba, open3d and torch to that many threads
    (parallel workers pass 1). ``rerun``: also write ``rerun``/<mesh>.rrd, every reconstruction
    under the entity path <planner>/start_<k>, side by side in the viewer (``nbvdata.view.rerun``)."""
    if threads:
        limit_threads(threads)
    try:
        obj = source.load(config.mesh)
        scene = Scene.build(obj, config, scene_rng(seed, source.mesh_id), threads)
    except (MeshError, ValueError, RuntimeError) as error:
        tick(len(planners) * (1 + random_starts))
        return [], [], str(error), None
    firsts = start_views(scene, source.mesh_id, random_starts, seed, config.episode.runs_per_mesh)
    floor_rows = [{"mesh": source.title, "start": number, "start_view": first}
                  | start_floor(scene, first, run_seed(seed, source.mesh_id, number))
                  for number, first in enumerate(firsts)] if floors else []
    cache = mesh_cache(scene, planners)
    rows = []
    with recording_of(rerun, source.title) as recording:
        for index, planner in enumerate(planners):
            for number, first in enumerate(firsts):
                log = recording.run([planner.name, f"start_{number}"], scene) if recording is not None else None
                try:
                    run = reconstruct(scene, planner, first, scans, run_seed(seed, source.mesh_id, number), log,
                                      cache=cache)
                except ConfigError:  # a policy that breaks its contract (e.g. returns no view): a user error
                    raise
                except Exception as error:  # a planner's bug (a user's policy too): this mesh fails, the rest go on
                    tick((len(planners) - index) * len(firsts) - number)
                    return [], [], (f"planner {planner.name} raised {type(error).__name__} from start view {first}: "
                                    f"{error} (the mesh's rows are left out, so that every planner is compared "
                                    "on the same meshes; tracebacks.txt has where)"), traceback.format_exc()
                rows += [{"mesh": source.title, "planner": planner.name, "start": number, "start_view": first} | row
                         for row in run]
                tick(1)
    return rows, floor_rows, None, None


def recording_of(folder: Path | None, mesh: str) -> contextlib.AbstractContextManager:
    """The Rerun recording ``folder``/<mesh>.rrd (``nbvdata.view.rerun.Recording``), or None."""
    if folder is None:
        return contextlib.nullcontext()
    from nbvdata.view.rerun import Recording

    return Recording(Path(folder) / f"{mesh}.rrd", mesh)


def limit_threads(threads: int) -> None:
    import numba
    import torch

    numba.set_num_threads(threads)
    torch.set_num_threads(threads)


@contextlib.contextmanager
def mesh_runner(workers: int, bar) -> Iterator[Callable]:
    """``run(function, argument tuples)``: the calls' results in order, in this process or in
    ``workers`` loky processes; each call counts its reconstructions on ``bar`` (through a queue
    from a worker process)."""
    if workers == 1:
        def run(function, calls):
            for arguments in calls:
                bar.set_postfix_str(arguments[0].title)
                yield function(*arguments, tick=bar.update)
        yield run
        return
    import multiprocessing

    import joblib

    with multiprocessing.Manager() as manager:
        ticks = manager.Queue()
        drain = threading.Thread(target=_drain, args=(ticks, bar), daemon=True)
        drain.start()
        try:
            with joblib.parallel_config(backend="loky", n_jobs=workers):
                yield lambda function, calls: joblib.Parallel(return_as="generator")(
                    joblib.delayed(function)(*arguments, tick=_QueueTick(ticks), threads=1) for arguments in calls)
        finally:
            ticks.put(None)
            drain.join()


class _QueueTick:
    """A worker's ``tick``: sends the count of finished reconstructions to the main process."""

    def __init__(self, ticks):
        self.ticks = ticks

    def __call__(self, runs: int) -> None:
        self.ticks.put(runs)


def _drain(ticks, bar) -> None:
    while (runs := ticks.get()) is not None:
        bar.update(runs)


def write_outputs(report: EvaluationReport, out: Path, planners: list[str], skipped: list[str],
                  settings: dict) -> None:
    """coverage.csv, summary.md, plots/*.png, config.yaml and (if any) failures.tsv in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "coverage.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        for row in report.rows:
            writer.writerow({key: f"{value:.6f}" if isinstance(value, float) else value for key, value in row.items()})
    with open(out / "floors.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=FLOOR_COLUMNS)
        writer.writeheader()
        writer.writerows(report.floors)
    (out / "summary.md").write_text(summary_markdown(report, planners, skipped))
    (out / "config.yaml").write_text(yaml.safe_dump(settings, sort_keys=False))
    write_failures(out, report.failures, report.tracebacks)
    if report.rows:
        plot_coverage(report.rows, out / "plots", report.floors)


def write_failures(out: Path, failures: list[tuple[str, str]], tracebacks: list[tuple[str, str]]) -> None:
    """failures.tsv (mesh, reason on one line) and tracebacks.txt in ``out``, each only when there
    is something to say; an earlier run's copies are removed first."""
    for name in ("failures.tsv", "tracebacks.txt"):
        (out / name).unlink(missing_ok=True)
    if failures:
        (out / "failures.tsv").write_text("mesh\treason\n" + "".join(f"{name}\t{' '.join(reason.split())}\n"
                                                                    for name, reason in failures))
    if tracebacks:
        (out / "tracebacks.txt").write_text("".join(f"== {name}\n{trace}\n" for name, trace in tracebacks))


def final_coverage(rows: list[dict], key: str = "coverage") -> dict[tuple[str, str], np.ndarray]:
    """(mesh, planner) -> (starts,) coverage after each start's last scan."""
    last: dict[tuple[str, str, int], tuple[int, float]] = {}
    for row in rows:
        slot = (row["mesh"], row["planner"], row["start"])
        if slot not in last or row["scan"] > last[slot][0]:
            last[slot] = (row["scan"], row[key])
    finals = defaultdict(list)
    for (mesh, planner, _), (_, value) in sorted(last.items()):
        finals[(mesh, planner)].append(value)
    return {slot: np.array(values) for slot, values in finals.items()}


def _paper(mesh: str) -> tuple[float, float, float] | None:
    matches = [key for key in PAPER_COVERAGE if key in mesh.lower()]
    return PAPER_COVERAGE[matches[0]] if matches else None


def coverage_table(rows: list[dict], planners: list[str], key: str) -> list[str]:
    """Markdown rows: objects x planners, mean (+- std over starts) in %, the best (and any value
    printed the same) in bold, mean row."""
    finals = final_coverage(rows, key)
    meshes = sorted({mesh for mesh, _ in finals})
    planners = [p for p in planners if any((m, p) in finals for m in meshes)]
    with_paper = key == "coverage" and any(_paper(m) for m in meshes)
    header = "| object | " + " | ".join(planners) + (" | paper: classif. / regression / inf. gain |" if with_paper else " |")
    lines = [header, "|---" * (len(planners) + 1 + with_paper) + "|"]
    means = defaultdict(list)
    for mesh in meshes:
        values = {p: 100 * finals[(mesh, p)] for p in planners if (mesh, p) in finals}
        shown = {p: float(f"{v.mean():.1f}") for p, v in values.items()}  # as printed, so every tie is bold
        best = max(shown.values())
        cells = []
        for planner in planners:
            if planner not in values:
                cells.append("-")
                continue
            value = values[planner]
            means[planner].append(value.mean())
            text = f"{value.mean():.1f}" + (f" ± {value.std():.1f}" if len(value) > 1 else "")
            cells.append(f"**{text}**" if shown[planner] == best else text)
        paper = _paper(mesh)
        extra = [" / ".join(f"{v:.1f}" for v in paper) if paper else "-"] if with_paper else []
        lines.append(f"| {mesh} | " + " | ".join(cells + extra) + " |")
    mean_cells = [f"{np.mean(means[p]):.1f}" if means[p] else "-" for p in planners]
    lines.append("| **mean** | " + " | ".join(mean_cells + (["-"] if with_paper else [])) + " |")
    return lines


def summary_markdown(report: EvaluationReport, planners: list[str], skipped: list[str]) -> str:
    """The summary: coverage tables after the last scan, the time per NBV and the overlap rule."""
    rows = report.rows
    if not rows:
        return "\n".join(["# Closed-loop evaluation: no object evaluated", "",
                          f"Every mesh failed ({len(report.failures)}), so there is nothing to compare; "
                          "failures.tsv lists them (and tracebacks.txt where a planner raised).", "",
                          *[f"- {message}" for message in skipped],
                          *[f"- mesh {name} failed: {reason}" for name, reason in report.failures]]) + "\n"
    scans = max((row["scan"] for row in rows), default=0)
    starts = len({row["start"] for row in rows})
    lines = [f"# Closed-loop evaluation: {len({r['mesh'] for r in rows})} objects, {scans} scans, "
             f"{starts} start{'s' if starts != 1 else ''} per object", ""]
    lines += [f"Coverage (%) of the surface after scan {scans}" + (", mean ± std over starts" if starts > 1 else "")
              + "; best per object (and ties) in bold.", ""]
    lines += coverage_table(rows, planners, "coverage")
    lines += ["", f"Observable coverage (%) after scan {scans}: of the surface some candidate view can see.", ""]
    lines += coverage_table(rows, planners, "observable_coverage")
    lines += ["", *scans_table(rows, report.floors, planners)]
    lines += ["", "Time per NBV (the planner's decision; the paper's on a GTX 1080).", "",
              "| planner | median ms | mean ms | max ms | decisions | paper s |", "|---|---|---|---|---|---|"]
    times = defaultdict(list)
    for row in rows:
        if row["scan"] > 1:
            times[row["planner"]].append(1e3 * row["seconds"])
    for planner in planners:
        if times[planner]:
            t = np.array(times[planner])
            paper = PAPER_SECONDS.get(planner)
            lines.append(f"| {planner} | {np.median(t):.2f} | {t.mean():.2f} | {t.max():.2f} | {len(t)} | "
                         f"{paper if paper is not None else '-'} |")
    lines += ["", *overlap_table(rows, planners, report.min_overlap)]
    if skipped or report.failures:
        lines.append("")
    lines += [f"- {message}" for message in skipped]
    lines += [f"- mesh {name} failed: {reason}" for name, reason in report.failures]
    return "\n".join(lines) + "\n"


def scans_to(rows: list[dict], targets: tuple[float, ...] = TARGETS) -> dict[tuple[str, str], list[list]]:
    """(mesh, planner) -> per start (in start order), per target: the first scan whose observable
    coverage reaches the target (the start scan counts), None when no scan does."""
    runs = defaultdict(dict)
    for row in rows:
        runs[(row["mesh"], row["planner"], row["start"])][row["scan"]] = row["observable_coverage"]
    result = defaultdict(list)
    for (mesh, planner, _), coverage in sorted(runs.items()):
        result[(mesh, planner)].append([next((scan for scan in sorted(coverage) if coverage[scan] >= target - 1e-9),
                                             None) for target in targets])
    return dict(result)


def scans_table(rows: list[dict], floors: list[dict], planners: list[str]) -> list[str]:
    """Markdown: scans to reach 90 / 95 / 99 % of the observable surface per object and planner
    (mean over starts; "n.r." when some start did not within the run's scans), beside the floor
    (1 + the optimal cover of what the start scan left: the fewest scans to 100 %) and the greedy
    set cover's scans."""
    reached = scans_to(rows)
    meshes = sorted({mesh for mesh, _ in reached})
    planners = [p for p in planners if any((m, p) in reached for m in meshes)]
    if not meshes:
        return []
    targets = " / ".join(f"{100 * t:g}" for t in TARGETS)
    lines = [f"Scans to reach {targets} % of the observable surface (the start scan counts; mean over starts; "
             "n.r.: not reached within the run's scans by some start). Floor: 1 + the fewest views that cover "
             "all that the start scan left (the set cover, proved optimal unless marked >=): no planner reaches "
             "100 % in fewer scans. Greedy cover: 1 + the greedy set cover's size (most new points first).", "",
             "| object | " + " | ".join(planners) + " | floor (100 %) | greedy cover (100 %) |",
             "|---" * (len(planners) + 3) + "|"]
    by_mesh = defaultdict(list)
    for floor in floors:
        by_mesh[floor["mesh"]].append(floor)
    for mesh in meshes:
        cells = []
        for planner in planners:
            if (mesh, planner) not in reached:
                cells.append("-")
                continue
            per_start = np.array(reached[(mesh, planner)], dtype=object)  # (starts, targets)
            cells.append(" / ".join("n.r." if any(v is None for v in column) else f"{np.mean(column.astype(float)):.1f}"
                                    for column in per_start.T))
        mesh_floors = by_mesh.get(mesh, [])
        if mesh_floors:
            sizes = np.array([1 + f["cover_size"] for f in mesh_floors], dtype=float)
            proved = all(f["cover_bound"] == f["cover_size"] for f in mesh_floors)
            bound = np.mean([1 + f["cover_bound"] for f in mesh_floors])
            floor = f"{sizes.mean():.1f}" if proved else f">= {bound:.1f} (best {sizes.mean():.1f})"
            greedy = f"{np.mean([1 + f['cover_greedy'] for f in mesh_floors]):.1f}"
        else:
            floor = greedy = "-"
        lines.append(f"| {mesh} | " + " | ".join(cells) + f" | {floor} | {greedy} |")
    return lines


def overlap_table(rows: list[dict], planners: list[str], min_overlap: float) -> list[str]:
    """Markdown: per planner, the share of decisions whose pose broke the overlap rule, and of
    decisions taken where no candidate view passed it (so even the oracle had to)."""
    lines = [f"Overlap rule: decisions whose chosen pose had an overlap under {100 * min_overlap:g} % (the oracle's "
             "overlap, of what the pose's scan covered: the share already covered before it), and decisions "
             "taken where no candidate view was valid, i.e. passed the rule and added surface (the oracle then "
             "takes the most informative view; this includes states with all the observable surface covered). "
             "Infogain checks the rule on an estimate from the grid; regression, classification and random never "
             "check it.", "",
             "| planner | decisions | overlap under the rule | no valid candidate view |", "|---|---|---|---|"]
    for planner in planners:
        decisions = [row for row in rows if row["planner"] == planner and row["scan"] > 1]
        if decisions:
            broke = sum(row["overlap"] < min_overlap for row in decisions)
            none_valid = sum(row["valid_views"] == 0 for row in decisions)
            lines.append(f"| {planner} | {len(decisions)} | {100 * broke / len(decisions):.1f} % ({broke}) | "
                         f"{100 * none_valid / len(decisions):.1f} % ({none_valid}) |")
    return lines


def plot_coverage(rows: list[dict], folder: Path, floors: list[dict] = ()) -> list[Path]:
    """One PNG per object: coverage (%) against scans, a line per planner (mean over starts,
    shaded from the lowest to the highest start; the legend and title say so), and a dotted line at
    the floor: the fewest scans that cover all the observable surface (mean over starts, ``floors``).
    The x axis spans the scans made; a floor beyond them is named in the legend, not drawn (a
    torus's 58 scans squeezed the 10 made into a tenth of the width)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator

    folder.mkdir(parents=True, exist_ok=True)
    series = defaultdict(lambda: defaultdict(dict))  # mesh -> planner -> start -> {scan: coverage}
    for row in rows:
        series[row["mesh"]][row["planner"]].setdefault(row["start"], {})[row["scan"]] = 100 * row["coverage"]
    paths = []
    for mesh, planners in sorted(series.items()):
        figure, axes = plt.subplots(figsize=(6, 4))
        counts = {len(starts) for starts in planners.values()}
        for planner, starts in planners.items():
            scans = sorted(next(iter(starts.values())))
            values = np.array([[start[s] for s in scans] for start in starts.values()])
            (line,) = axes.plot(scans, values.mean(axis=0), marker="o", markersize=3, label=planner)
            if len(values) > 1:
                axes.fill_between(scans, values.min(axis=0), values.max(axis=0), color=line.get_color(), alpha=0.15)
        made = sorted({scan for starts in planners.values() for start in starts.values() for scan in start})
        sizes = [1 + floor["cover_size"] for floor in floors if floor["mesh"] == mesh]
        floor = float(np.mean(sizes)) if sizes else None
        if floor is not None and floor <= made[-1] + 0.5:
            axes.axvline(floor, color="0.4", linestyle=":", label="floor: fewest scans to all observable")
        handles = axes.get_legend_handles_labels()[0]
        if floor is not None and floor > made[-1] + 0.5:
            handles.append(Line2D([], [], color="0.4", linestyle=":",
                                  label=f"floor: fewest scans to all observable, {floor:g} (beyond the plot)"))
        title = mesh
        if max(counts) > 1:  # lines are means over the starts, bands their range
            starts = f"{max(counts)} starts" if len(counts) == 1 else "the starts"
            title = f"{mesh}: mean of {starts}"
            handles.append(Patch(color="0.5", alpha=0.25, label=f"shaded: lowest to highest of {starts}"))
        axes.set(xlabel="scan", ylabel="coverage (%)", title=title, ylim=(0, 100), xlim=(made[0] - 0.5, made[-1] + 0.5))
        axes.xaxis.set_major_locator(MaxNLocator(integer=True))  # scans are whole: no tick at 1.5
        axes.grid(alpha=0.3)
        axes.legend(handles=handles, loc="lower right", fontsize=8)
        figure.tight_layout()
        path = folder / f"{mesh}.png"  # a mesh named by its path (stems that collide): in its folders
        path.parent.mkdir(parents=True, exist_ok=True)
        figure.savefig(path, dpi=100)
        plt.close(figure)
        paths.append(path)
    return paths


def settings_dict(config: SimConfig, **arguments) -> dict:
    """config.yaml's content: the evaluation's arguments, then the simulation settings."""
    return {"evaluate": {key: str(value) if isinstance(value, Path) else value for key, value in arguments.items()},
            **to_dict(config)}
