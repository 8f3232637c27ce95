"""The dataset job: labelled reconstructions of many meshes, in parallel, resumable, to shards.

The work is split into units - one mesh and a range of its runs - each written to its own
shard (``nbvdata.schema.shards``). Every seed derives from the global seed, the mesh id and the run
number (``nbvdata.simulation.episode``), never from the unit or the worker, so any number of workers on
any joblib backend (Dask included) gives the same arrays. A unit whose shard exists is done:
running the same command again after a kill continues with the missing units. A mesh that
cannot be used is reported and listed in ``failures.tsv``; the others go on.

Several processes, on one machine or on several sharing a filesystem, may run the same job into
one folder at once: each unit is claimed by one of them (``nbvdata.datasets.claims``), the others leave it
to that one and go on with the rest.

With a policy (``--policy``, ``nbvdata.simulation.policy``) the runs follow a trained planner: every worker
loads it from the checkpoint's path itself, the folder's ``policy.yaml`` and every shard's
``policy`` attribute record the checkpoint's sha256, and a folder holds the runs of one policy
(or of none).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import queue
import sys
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import yaml

from nbvdata import __version__
from nbvdata.core.config import ConfigError, SimConfig
from nbvdata.core.files import sweep_temporaries, write_atomic
from nbvdata.datasets.claims import claim, drop_partials, folder_lock, partial_path, sweep_partials
from nbvdata.schema.shards import COVER, GENERATED, MOVES, GridPalette, Shard, ShardError, write_shard
from nbvdata.simulation.episode import LabelledRun, Mover, ViewCache, run_reconstruction, run_seed, start_view
from nbvdata.simulation.mesh import MeshError, ObjectMesh
from nbvdata.simulation.policy import DEFAULT_PROVIDER, PolicySource, check_policy, load_policy
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.sources import (MeshSource, SceneCache,  # noqa: F401 (the job's sources, named here too)
                                        builtin_sources, mesh_sources, part_sources)

CONFIG_FILE = "config.yaml"
POLICY_FILE = "policy.yaml"
FAILURES_FILE = "failures.tsv"
RERUN_FOLDER = "rerun"  # --rerun-runs: one recording per shard, named as it (nbvdata.view.rerun)


@dataclass(frozen=True)
class Unit:
    """Runs [runs[0], runs[1]) of one mesh, written to one shard."""

    source: MeshSource
    runs: tuple[int, int]

    @property
    def shard_name(self) -> str:
        return f"{self.source.slug}-{self.source.mesh_id[:12]}-runs{self.runs[0]:04d}-{self.runs[1]:04d}.h5"

    @property
    def run_count(self) -> int:
        return self.runs[1] - self.runs[0]


def plan_units(sources: list[MeshSource], config: SimConfig) -> list[Unit]:
    """Every (mesh, run range) unit of the job, in a fixed order."""
    runs = config.episode.runs_per_mesh
    step = config.generate.runs_per_shard or runs
    return [Unit(source, (start, min(start + step, runs))) for source in sources for start in range(0, runs, step)]


@dataclass
class UnitResult:
    """What a worker reports back for one unit. ``elsewhere``: left to another process, which
    "holds" the unit or has "done" it (then nothing was run here)."""

    unit: Unit
    samples: int = 0
    error: str | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    elsewhere: str | None = None
    cover_seconds: list[tuple[int, float]] = field(default_factory=list)  # (step, seconds) per label


class Timer:
    """Seconds spent per phase: ``with timer("scan"): ...``."""

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)

    @contextlib.contextmanager
    def __call__(self, phase: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[phase] += time.perf_counter() - start


def run_unit(unit: Unit, config: SimConfig, out_dir: Path, progress: Callable[[int, int], None] | None = None,
             threads: int = 0, policy: PolicySource | None = None, rerun_runs: int = 0) -> UnitResult:
    """Claim the unit, simulate and label its runs and write its shard. Never raises for a bad
    mesh: the reason comes back in ``UnitResult.error``. A unit another process holds, or has
    finished, is left to it (``UnitResult.elsewhere``). ``progress(runs, samples)`` is called per
    run. ``threads`` > 0 limits numba, open3d and torch to that many threads (parallel workers
    pass 1). ``policy``: the checkpoint the runs follow (loaded here, once per process).
    ``rerun_runs``: runs 0..rerun_runs-1 of the mesh are also recorded, after the shard is
    written, to ``RERUN_FOLDER``/<shard name>.rrd (``record_unit``)."""
    out_dir = Path(out_dir)
    with claim(out_dir, unit.shard_name) as mine:
        if not mine:
            return UnitResult(unit, elsewhere="holds")
        shard = out_dir / unit.shard_name
        if _shard_problem(shard) is None:
            return UnitResult(unit, elsewhere="done")
        shard.unlink(missing_ok=True)  # broken: redone
        drop_partials(out_dir, unit.shard_name)  # a dead process's: the claim is ours
        sweep_temporaries(out_dir / RERUN_FOLDER, [recording_name(unit)])  # its recording's too
        return _run_claimed(unit, config, out_dir, progress, threads, policy, rerun_runs)


def _run_claimed(unit: Unit, config: SimConfig, out_dir: Path, progress: Callable[[int, int], None] | None,
                 threads: int, policy: PolicySource | None = None, rerun_runs: int = 0) -> UnitResult:
    """``run_unit`` once the unit is claimed."""
    result = UnitResult(unit)
    recorded_runs: list[tuple[int, LabelledRun]] = []  # (run, record) of the runs to record
    timer = Timer()
    if threads:
        import numba
        numba.set_num_threads(threads)
    try:
        seed, mesh_id = config.episode.seed, unit.source.mesh_id
        with timer("scene"):
            obj, scene, cache = _mesh_scene(unit.source, config, threads)
        with timer("policy"):
            planner = load_policy(policy, config, threads) if policy is not None else None
        episode = config.episode
        recorded = ("nbv_index", "gains", "overlaps", "coverage", "last_view")
        if episode.explore > 0 or planner is not None:  # off the oracle's path: record the moves
            recorded += tuple(sorted(MOVES))
        if config.oracle.cover:
            recorded += tuple(sorted(COVER))
            with timer("cover_mesh"):  # the mesh's own cover, which bounds every run's first state
                scene.empty_cover()
        if config.state.points:
            recorded += ("points", "points_count")
        columns: dict[str, list] = defaultdict(list)
        palette = GridPalette()
        for run in range(*unit.runs):
            rng_seed = run_seed(seed, mesh_id, run)
            mover = Mover.for_run(episode.explore, planner, episode.oracle_mix, seed, mesh_id, run)
            with timer("runs"):
                record = run_reconstruction(scene, start_view(seed, mesh_id, len(scene.views), run),
                                            np.random.default_rng(rng_seed), cache, mover)
            with timer("encode"):
                columns["grids"].extend(palette.encode(log_odds) for log_odds in record.log_odds)
            for name in recorded:
                columns[name].extend(getattr(record, name))
            columns["run"].extend([run] * len(record))
            columns["step"].extend(range(1, len(record) + 1))
            columns["seed"].extend([rng_seed] * len(record))
            if run < rerun_runs:
                recorded_runs.append((run, record))
            result.cover_seconds += list(enumerate(record.cover_seconds, start=1))
            if progress is not None:
                progress(1, len(record))
        with timer("write"):
            arrays = _assemble(columns, scene, palette, mesh_id)
            attrs = {
                "package_version": __version__,
                "config": yaml.safe_dump(config.dataset_dict(), sort_keys=False),
                "meshes": json.dumps([{"id": mesh_id, "source": unit.source.recorded, "sha256": mesh_id}],
                                     allow_nan=False),
                "samples": len(arrays["nbv_index"]),
                "runs": np.array(unit.runs, dtype=np.int64),
                "source": GENERATED,
            }
            if policy is not None:
                attrs["policy"] = json.dumps(dataclasses.replace(policy, name=planner.name).record(), allow_nan=False)
            write_shard(out_dir / unit.shard_name, arrays, attrs, partial_path(out_dir / unit.shard_name))
        result.samples = len(arrays["nbv_index"])
    except MeshError as error:
        result.error = str(error)
    except Exception as error:  # a mesh that breaks the simulation must not stop the others
        logging.getLogger(__name__).debug("unit %s failed", unit.shard_name, exc_info=True)
        result.error = f"{type(error).__name__}: {error}"
    if recorded_runs and result.error is None:
        with timer("record"):
            record_unit(out_dir / RERUN_FOLDER / recording_name(unit), scene,
                        recorded_runs)
    result.seconds = dict(timer.seconds)
    return result


def recording_name(unit: Unit) -> str:
    """The file name of a unit's recording in ``RERUN_FOLDER``: its shard's, as .rrd."""
    return Path(unit.shard_name).with_suffix(".rrd").name


def record_unit(path: Path, scene: Scene, runs: list[tuple[int, LabelledRun]]) -> None:
    """Write the Rerun recording of a unit's first runs ((run, record) pairs), each under the
    entity path run_NNNN (``nbvdata.view.rerun``). A recording that cannot be written is logged as
    a warning: the shard, written before, stands."""
    from nbvdata.view.rerun import Recording, log_record

    try:
        with Recording(path, path.stem) as recording:
            for run, record in runs:
                log_record(recording.run([f"run_{run:04d}"], scene), record)
    except Exception as error:
        logging.getLogger(__name__).warning("could not write the recording %s: %s: %s", path,
                                            type(error).__name__, error)


# Scenes of the meshes this thread ran last: the units of one mesh (runs_per_shard > 0) come one
# after another, so a worker casts each mesh's scene once, not once per unit. Per thread, since a
# scene's view cache has scratch buffers (the threading backend runs units side by side).
SCENE_CACHE_SIZE = 2
_SCENES = threading.local()


def clear_scene_caches(size: int = SCENE_CACHE_SIZE) -> None:
    """Forget the scenes every thread of this process kept, and keep ``size`` meshes' from now on
    (0: none, each unit casts its mesh's scene again; ``benchmarks/scene_reuse.py``)."""
    global SCENE_CACHE_SIZE, _SCENES
    SCENE_CACHE_SIZE, _SCENES = size, threading.local()


def _mesh_scene(source: MeshSource, config: SimConfig, threads: int) -> tuple[ObjectMesh, Scene, ViewCache | None]:
    """(mesh, scene, view cache) of ``source`` under ``config``'s data settings, from this
    thread's ``SceneCache`` of ``SCENE_CACHE_SIZE`` meshes."""
    if not hasattr(_SCENES, "cache"):
        _SCENES.cache = SceneCache(SCENE_CACHE_SIZE)
    return _SCENES.cache.get(source, config, threads)


def _assemble(columns: dict[str, list], scene: Scene, palette: GridPalette, mesh_id: str) -> dict[str, np.ndarray]:
    """The unit's lists of per-state values as the shard's arrays."""
    n, views = scene.config.grid.size, len(scene.views)
    count = len(columns["nbv_index"])
    code_type = np.uint8 if len(palette) <= 256 else np.uint16
    nbv = np.asarray(columns["nbv_index"], dtype=np.int32)
    xyzypr = scene.views.xyzypr()
    return {
        "grids": np.asarray(columns["grids"], dtype=code_type).reshape(count, n, n, n),
        "grid_palette": palette.probabilities(),
        "nbv_index": nbv,
        "nbv_pose": xyzypr[nbv].reshape(count, 6),
        "nbv_position": scene.views.unit_positions[nbv].astype(np.float32).reshape(count, 3),
        "gains": np.asarray(columns["gains"], dtype=np.float32).reshape(count, views),
        "overlaps": np.asarray(columns["overlaps"], dtype=np.float32).reshape(count, views),
        "coverage": np.asarray(columns["coverage"], dtype=np.float32).reshape(count, 2),
        "mesh_id": np.full(count, mesh_id.encode(), dtype="S64"),
        "run": np.asarray(columns["run"], dtype=np.int32),
        "step": np.asarray(columns["step"], dtype=np.int32),
        "last_view": np.asarray(columns["last_view"], dtype=np.int32),
        "seed": np.asarray(columns["seed"], dtype=np.int64),
        "view_positions": scene.views.positions,
        "view_poses": xyzypr,
    } | ({
        "move": np.asarray(columns["move"], dtype=np.int8),
        "next_view": np.asarray(columns["next_view"], dtype=np.int32),
        "next_pose": np.asarray(columns["next_pose"], dtype=np.float64).reshape(count, 6),
    } if "move" in columns else {}) | ({
        "cover": np.asarray(columns["cover"], dtype=bool).reshape(count, views),
        "cover_size": np.asarray(columns["cover_size"], dtype=np.int16),
        "cover_bound": np.asarray(columns["cover_bound"], dtype=np.int16),
        "cover_greedy": np.asarray(columns["cover_greedy"], dtype=np.int16),
    } if "cover" in columns else {}) | ({
        "points": np.asarray(columns["points"], dtype=np.float32).reshape(count, scene.config.state.points, 3),
        "points_count": np.asarray(columns["points_count"], dtype=np.int32),
        "reference_points": scene.coverage.points.astype(np.float32),
    } if scene.config.state.points else {}) | ({
        "surface": scene.surface_voxels(),
    } if scene.config.state.surface else {})


# ---------------------------------------------------------------------------------------------
# The job


@dataclass
class Report:
    """The outcome of one ``generate`` call. ``others_done``: units another process finished
    meanwhile; ``others_running``: units another process still held when this one was done."""

    out_dir: Path
    done: list[UnitResult] = field(default_factory=list)
    skipped: list[Unit] = field(default_factory=list)
    failures: list[tuple[str, str]] = field(default_factory=list)
    seconds: float = 0.0
    others_done: list[Unit] = field(default_factory=list)
    others_running: list[Unit] = field(default_factory=list)

    @property
    def samples(self) -> int:
        return sum(r.samples for r in self.done)


def prepare_out_dir(out_dir: Path, config: SimConfig, policy: PolicySource | None = None) -> None:
    """Create ``out_dir``, or check that the dataset there was made with the same data settings
    and the same policy (or none); delete the partial files of killed runs (not those of runs
    still going)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    settings, policy_file = out_dir / CONFIG_FILE, out_dir / POLICY_FILE
    wanted = config.dataset_dict()
    with folder_lock(out_dir):  # one process writes config.yaml, the others check it
        if settings.exists():
            existing = yaml.safe_load(settings.read_text()) or {}
            if existing != wanted:
                sections = list(wanted) + [section for section in existing if section not in wanted]
                differ = sorted({f"{section}.{key}" for section in sections
                                 for key in [*wanted.get(section, {}), *existing.get(section, {})]
                                 if existing.get(section, {}).get(key) != wanted.get(section, {}).get(key)})
                raise ConfigError(f"{out_dir} holds shards made with other settings ({', '.join(differ)}): "
                                  "use a new --out folder, or the settings in "
                                  f"{settings} to resume")
            followed = yaml.safe_load(policy_file.read_text()) if policy_file.exists() else None
            if _policy_key(followed) != _policy_key(policy.record() if policy else None):
                raise ConfigError(f"{out_dir} holds runs that follow {_policy_words(followed)}, not "
                                  f"{_policy_words(policy.record() if policy else None)}: use a new --out folder"
                                  + (f", or --policy with the checkpoint of sha256 {followed['sha256']} to resume"
                                     if followed else ", or leave out --policy to resume"))
        else:  # policy.yaml first: config.yaml marks the folder as begun
            if policy is not None:
                write_atomic(policy_file, yaml.safe_dump(policy.record(), sort_keys=False))
            else:
                policy_file.unlink(missing_ok=True)  # left by a job killed before it began
            write_atomic(settings, yaml.safe_dump(wanted, sort_keys=False))
    sweep_partials(out_dir)
    sweep_temporaries(out_dir)
    sweep_temporaries(out_dir / RERUN_FOLDER)


def _policy_key(record: dict | None) -> tuple[str, str] | None:
    """What makes two policies the same: the file's sha256 and the provider reading it."""
    return None if record is None else (record["sha256"], record.get("provider", DEFAULT_PROVIDER))


def _policy_words(record: dict | None) -> str:
    """"the oracle" or "the policy nbvnet-4-5 epoch 12 (sha256 0123456789ab...)" (with its
    provider when not the default)."""
    if record is None:
        return "the oracle (no --policy)"
    provider = record.get("provider", DEFAULT_PROVIDER)
    provider = f" of provider {provider}" if provider != DEFAULT_PROVIDER else ""
    return f"the policy {record.get('network') or 'checkpoint'}{provider} (sha256 {record['sha256'][:12]}...)"


def _shard_problem(path: Path) -> str | None:
    """None for a whole shard, else why not: "absent" or what is wrong with the file (every dataset
    is read: its checksums and value ranges, ``Shard.check``)."""
    if not path.exists():
        return "absent"
    try:
        with Shard(path) as shard:
            shard.check()
    except ShardError as error:
        return str(error)
    return None


def _completed(path: Path) -> bool:
    """True for a readable shard; a broken one is reported, and replaced by whoever claims its unit."""
    problem = _shard_problem(path)
    if problem not in (None, "absent"):
        print(f"nbvdata generate: redoing {path.name}: {problem}")
    return problem is None


def generate(sources: list[MeshSource], out_dir: Path, config: SimConfig,
             failures: list[tuple[str, str]] = (), show_progress: bool | None = None,
             policy: PolicySource | None = None, rerun_runs: int = 0) -> Report:
    """Run every unit not yet in ``out_dir`` and not claimed by another process; returns what was
    done, skipped, failed and left to others.

    Units another process held are tried again after the others: those it has given up (killed)
    are done here. ``show_progress`` None shows the bar only on a terminal. ``policy``: the
    checkpoint the runs follow (loaded here first, so that a bad one fails at once).
    ``rerun_runs``: also record the first that many runs of each mesh, one Rerun recording per
    shard in ``out_dir``/``RERUN_FOLDER``, written by the worker that writes the shard (units
    already done are not run again, so not recorded); the shards are the same bytes.
    """
    from tqdm import tqdm

    start = time.perf_counter()
    out_dir = Path(out_dir)
    if policy is None and config.episode.oracle_mix > 0:
        raise ConfigError(f"episode.oracle_mix={config.episode.oracle_mix} mixes oracle moves into a policy's: "
                          "pass --policy CHECKPOINT too, or leave it 0")
    if policy is not None:
        policy = check_policy(policy, config)
    prepare_out_dir(out_dir, config, policy)
    report = Report(out_dir, failures=list(failures))
    for name, reason in failures:
        print(f"nbvdata generate: failed: {name}: {reason}", file=sys.stderr)
    units = plan_units(sources, config)
    todo = []
    for unit in units:
        (report.skipped if _completed(out_dir / unit.shard_name) else todo).append(unit)
    workers = config.generate.workers or os.cpu_count() or 1
    bar = tqdm(total=sum(u.run_count for u in todo), unit="run", desc="generate", disable=None if show_progress is None
               else not show_progress, dynamic_ncols=True)
    counts = {"samples": 0}

    def advance(runs: int, samples: int) -> None:
        counts["samples"] += samples
        bar.update(runs)
        elapsed = max(bar.format_dict["elapsed"], 1e-9)
        bar.set_postfix(samples=counts["samples"], per_s=f"{counts['samples'] / elapsed:.1f}", refresh=False)

    def finished(result: UnitResult, ticked: bool) -> None:
        """A unit came back; ``ticked``: its runs were already counted, one by one."""
        if result.elsewhere is not None:
            bar.total -= result.unit.run_count
            bar.refresh()
            (report.others_running if result.elsewhere == "holds" else report.others_done).append(result.unit)
            return
        if not ticked:
            advance(result.unit.run_count, result.samples)
        if result.error is None:
            report.done.append(result)
        else:
            name = str(result.unit.source.path or result.unit.source.name)
            reason = result.error.removeprefix(f"{name}: ")  # a MeshError names its file: said once, in name
            report.failures.append((name, reason))
            bar.write(f"nbvdata generate: failed: {result.unit.source.name}: {reason}", file=sys.stderr)

    try:
        with _executor(config, out_dir, workers, advance, policy, rerun_runs) as (execute, ticked):
            while todo:
                for result in execute(todo):
                    finished(result, ticked)
                held, report.others_running = report.others_running, []
                if len(held) == len(todo):  # none was given up: their holders are still at work
                    report.others_running = held
                    break
                todo = held  # again: a holder that died has released them
                bar.total += sum(u.run_count for u in todo)
    finally:
        bar.close()
        _write_failures(out_dir, report.failures, units)
        report.seconds = time.perf_counter() - start
    return report


@contextlib.contextmanager
def _executor(config: SimConfig, out_dir: Path, workers: int, advance: Callable[[int, int], None],
              policy: PolicySource | None = None, rerun_runs: int = 0
              ) -> Iterator[tuple[Callable[[list[Unit]], Iterator[UnitResult]], bool]]:
    """``(execute, ticked)``: ``execute(units)`` runs units and yields their results as they come
    back, in-process or on a joblib backend (one thread per worker); ``ticked``: their runs are
    counted through ``advance`` one by one. Each worker claims its unit itself (``run_unit``), so
    the claim is held by the process that writes the shard, whatever the backend."""
    if workers == 1 and config.generate.backend != "dask":
        yield (lambda units: (run_unit(unit, config, out_dir, advance, policy=policy, rerun_runs=rerun_runs)
                              for unit in units)), True
        return
    import joblib

    backend = config.generate.backend
    with contextlib.ExitStack() as stack:
        ticks = None
        if backend == "dask":
            stack.enter_context(_dask_client(config.generate.scheduler, workers))
        elif backend == "threading":
            ticks = queue.Queue()
        else:
            import multiprocessing
            ticks = stack.enter_context(multiprocessing.Manager()).Queue()
        if ticks is not None:
            drain = threading.Thread(target=_drain, args=(ticks, advance), daemon=True)
            drain.start()
            stack.callback(drain.join)
            stack.callback(ticks.put, None)
        stack.enter_context(joblib.parallel_config(backend=backend, n_jobs=workers))
        progress = _QueueProgress(ticks) if ticks is not None else None

        def execute(units: list[Unit]) -> Iterator[UnitResult]:
            calls = (joblib.delayed(run_unit)(unit, config, out_dir, progress, 1, policy, rerun_runs) for unit in units)
            yield from joblib.Parallel(return_as="generator_unordered")(calls)

        yield execute, ticks is not None


class _QueueProgress:
    """A worker's progress callback: sends (runs, samples) to the main process."""

    def __init__(self, ticks):
        self.ticks = ticks

    def __call__(self, runs: int, samples: int) -> None:
        self.ticks.put((runs, samples))


def _drain(ticks, advance: Callable[[int, int], None]) -> None:
    while (tick := ticks.get()) is not None:
        advance(*tick)


SCHEDULER_WAIT = 30  # seconds to reach a --scheduler before saying it is not there


@contextlib.contextmanager
def _dask_client(scheduler: str | None, workers: int) -> Iterator[object]:
    """A client of the cluster at ``scheduler``, or of a local cluster of ``workers`` processes."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise ConfigError("generate.backend dask needs dask.distributed: pip install 'nbv-regression[dask]'") from None
    if scheduler:
        try:
            client = Client(scheduler, timeout=SCHEDULER_WAIT)
        except (OSError, TimeoutError) as error:
            raise ConfigError(f"--scheduler {scheduler}: no Dask scheduler answered within {SCHEDULER_WAIT} s "
                              f"({type(error).__name__}): start one (dask scheduler) and its workers, or check the "
                              "address") from None
        with client:
            yield client
    else:
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            yield client


def _write_failures(out_dir: Path, failures: list[tuple[str, str]], units: list[Unit]) -> None:
    """Merge this process's failures into ``failures.tsv``, under the folder lock. Entries already
    there (another process's, an earlier run's) are kept, but for a mesh of ``units`` whose shards
    are all there now; no entries left: no file."""
    path = out_dir / FAILURES_FILE
    with folder_lock(out_dir):
        entries = []
        if path.exists():
            lines = path.read_text().splitlines()[1:]
            entries = [tuple(line.split("\t", 1)) for line in lines if "\t" in line]
        missing = {str(u.source.path or u.source.name) for u in units if not (out_dir / u.shard_name).exists()}
        ours = {str(u.source.path or u.source.name) for u in units}
        kept = [entry for entry in entries if entry[0] not in ours or entry[0] in missing]
        clean = [(name, " ".join(reason.split())) for name, reason in failures]  # one line each
        merged = list(dict.fromkeys(kept + clean))
        if merged:
            write_atomic(path, "mesh\treason\n" + "".join(f"{name}\t{reason}\n" for name, reason in merged))
        elif path.exists():
            path.unlink()
