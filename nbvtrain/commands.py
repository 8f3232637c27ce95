"""The ``nbvtrain`` commands: what each subcommand does with its parsed arguments (``cmd_*``),
and what two of them share. ``nbvtrain.cli`` defines the options and dispatches to them.

Longer than 600 lines because it holds a handler for each of the seven subcommands and the small
argument readers they share; each handler only reads its arguments and hands the work to its stage.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from nbvdata.core.config import ConfigError, from_dict, load_config, to_dict
from nbvdata.core.text import plural
from nbvdata.core.userarrays import NOT_NPY, NpyError, file_kind, is_hdf5, read_npy
from nbvdata.schema.shards import Shard, ShardError, shard_files

INSTALL_TORCH = ('pip install -e ".[train]" in the checkout, or pip install torch (CPU only: pip install torch '
                 "--index-url https://download.pytorch.org/whl/cpu)")

FIT_FLAGS = {"model": "model", "epochs": "epochs", "batch_size": "batch_size", "lr": "lr",
             "lr_schedule": "lr_schedule", "score_loss": "score_loss",
             "regression_loss": "regression_loss", "near_best": "near_best", "dropout": "dropout",
             "dropout_from": "dropout_from", "split": "split", "val_fraction": "val_fraction",
             "augment": "augment", "seed": "seed", "device": "device", "threads": "threads",
             "mixed_scenes": "mixed_scenes", "init": "init"}


def cmd_fit(args: argparse.Namespace) -> int:
    """Train a network; with --resume continue the run in --out."""
    if args.model in RANKERS:
        return _fit_ranker(args)
    if args.model in COVER_MODELS:
        return _fit_cover(args)
    if args.model == SURFACE_MODEL:
        return _fit_surface(args)
    _only_options_of(args, "network")
    from nbvtrain.networks.config import TrainConfig
    from nbvtrain.networks.train import Interrupted, fit, load_run_config

    flags = {key: getattr(args, attr) for attr, key in FIT_FLAGS.items() if getattr(args, attr) is not None}
    out = args.out or Path("runs") / (flags.get("model") or TrainConfig.model)
    if args.resume:
        config = from_dict(TrainConfig, to_dict(load_run_config(out)) | flags)
    else:
        if not args.shards:
            raise ConfigError("no shards given: nbvtrain fit SHARDS_OR_FOLDERS... (or --resume --out RUN)")
        config = load_config(TrainConfig, args.config, args.overrides + [f"{k}={v}" for k, v in flags.items()])
    manifest = args.shards[0] if len(args.shards) == 1 and args.shards[0].suffix == ".json" else None
    shards = shard_files(args.shards) if args.shards and manifest is None else []
    added = shard_files(args.add_train) if args.add_train else []
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    started = time.perf_counter()
    try:
        result = fit(shards, config, out, resume=args.resume, progress=progress, manifest=manifest, root=args.root,
                     add_train=added)
    except Interrupted as stop:
        print(f"nbvtrain fit: {stop}; continue with: nbvtrain fit --resume --out {out}", file=sys.stderr)
        return 130
    print(f"nbvtrain fit: {plural(result.epochs, 'epoch')} in {out} ({time.perf_counter() - started:.1f} s); "
          f"best checkpoint {out / 'best.pt'}")
    return 0


RANKERS = ("viewrank-gbm", "viewrank-mlp")  # nbvtrain.ranking.viewrank.KINDS, without importing it for --help
RANKER_FLAGS = {"rays": "rays", "sample": "sample", "seed": "seed", "trees": "trees", "lr": "learning_rate",
                "epochs": "epochs", "threads": "threads", "features": "features", "label": "label",
                "mesh_weight": "mesh_weights"}


SPECIFIC = ("resume", "add_train", "init", "augment", "dropout", "dropout_from", "score_loss", "regression_loss",
            "batch_size", "lr_schedule", "near_best", "mixed_scenes", "config", "rays", "sample", "trees", "epochs",
            "width", "train_states", "feature_cache", "features", "label", "surface_prior", "mesh_weight")
"""fit's options that only some kinds of model take (``OPTIONS_OF``)."""
OPTIONS_OF = {
    "network": ("resume", "add_train", "init", "augment", "dropout", "dropout_from", "score_loss", "regression_loss",
                "batch_size", "lr_schedule", "near_best", "mixed_scenes", "config", "epochs"),
    "ranker": ("rays", "sample", "trees", "epochs", "feature_cache", "features", "label", "surface_prior",
               "mesh_weight"),
    "surface-gbm": ("trees",),
    "cover-gbm": ("rays", "sample", "trees", "feature_cache"),
    "scvp-net": ("epochs", "batch_size", "width", "train_states"),
}
"""The options of ``SPECIFIC`` each kind of model takes."""


def _only_options_of(args: argparse.Namespace, kind: str) -> None:
    """ConfigError naming the first option of ``SPECIFIC`` given that ``kind`` (``OPTIONS_OF``) does
    not take, and the models that do; for the models validated on whole meshes, ``--split random`` too."""
    for flag in SPECIFIC:
        if flag not in OPTIONS_OF[kind] and getattr(args, flag, None) not in (None, False, []):
            takers = [other for other, flags in OPTIONS_OF.items() if flag in flags]
            what = "a network" if kind == "network" else f"{args.model}"
            raise ConfigError(f"--{flag.replace('_', '-')}: not an option of {what} (but of {', '.join(takers)}); "
                              "leave it out")
    if kind != "network" and args.split == "random":
        raise ConfigError(f"--split random: {args.model} is validated on whole meshes (the mesh split); leave --split out")


def _fit_ranker(args: argparse.Namespace) -> int:
    """``fit --model viewrank-*``: a ranker of candidate views on manifests or shard folders."""
    from nbvtrain.ranking.rankfit import DEFAULT_CACHE, describe, fit_ranker
    from nbvtrain.ranking.viewrank import RankerConfig

    _only_options_of(args, "ranker")
    settings = {key: getattr(args, attr) for attr, key in RANKER_FLAGS.items() if getattr(args, attr) is not None}
    config = RankerConfig(model=args.model, **settings)
    out = args.out or Path("runs") / args.model
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    cache = None if args.feature_cache == Path("none") else (args.feature_cache or DEFAULT_CACHE)
    started = time.perf_counter()
    metrics = fit_ranker(args.shards, config, out, target=args.target, root=args.root, workers=args.workers,
                         cache=cache, progress=progress, prior=args.surface_prior)
    print(f"nbvtrain fit: {describe(metrics)}; {out / metrics['file']} ({time.perf_counter() - started:.0f} s)")
    return 0


COVER_MODELS = ("cover-gbm", "scvp-net")  # nbvtrain.ranking.covermodel, nbvtrain.ranking.covernet
SURFACE_MODEL = "surface-gbm"  # nbvtrain.ranking.surfaceprior


def _fit_surface(args: argparse.Namespace) -> int:
    """``fit --model surface-gbm``: a surface prior on shards with the meshes' surface voxels."""
    from nbvtrain.ranking.surfaceprior import SurfacePriorConfig, fit_surface_prior

    _only_options_of(args, args.model)
    settings = {key: getattr(args, attr) for attr, key in (("seed", "seed"), ("trees", "trees"), ("lr", "learning_rate"),
                                                           ("threads", "threads")) if getattr(args, attr) is not None}
    out = args.out or Path("runs") / args.model
    started = time.perf_counter()
    metrics = fit_surface_prior(args.shards, SurfacePriorConfig(**settings), out, root=args.root, workers=args.workers)
    figures = metrics["val"]["all"]
    print(f"nbvtrain fit: surface-gbm: validation precision {figures['precision']:.3f}, recall {figures['recall']:.3f} "
          f"of the hidden surface voxels on {plural(metrics['val_states'], 'state')}; {out / 'surface.json'} "
          f"({time.perf_counter() - started:.0f} s)")
    return 0


def _fit_cover(args: argparse.Namespace) -> int:
    """``fit --model cover-gbm|scvp-net``: a set-cover model on manifests or shard folders with covers."""
    _only_options_of(args, args.model)
    out = args.out or Path("runs") / args.model
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    started = time.perf_counter()
    if args.model == "cover-gbm":
        from nbvtrain.ranking.covermodel import CoverModelConfig, fit_cover_model
        from nbvtrain.ranking.rankfit import DEFAULT_CACHE

        names = {"rays": "rays", "sample": "sample", "seed": "seed", "trees": "trees", "lr": "learning_rate",
                 "threads": "threads"}
        config = CoverModelConfig(**{key: getattr(args, attr) for attr, key in names.items()
                                     if getattr(args, attr) is not None})
        cache = None if args.feature_cache == Path("none") else (args.feature_cache or DEFAULT_CACHE)
        metrics = fit_cover_model(args.shards, config, out, root=args.root, workers=args.workers, cache=cache,
                                  progress=progress)
        val = metrics["val"]
        print(f"nbvtrain fit: cover-gbm: validation sets of {val['predicted_size']:.2f} views against optimal "
              f"{val['optimal_size']:.2f}, precision {val['precision']:.3f}, recall {val['recall']:.3f} (the expected "
              f"size's most probable views) on {plural(val['states'], 'state')}; {out / 'cover.json'} "
              f"({time.perf_counter() - started:.0f} s)")
        return 0
    from nbvtrain.ranking.covernet import CoverNetConfig, fit_covernet

    names = {"width": "width", "epochs": "epochs", "batch_size": "batch", "lr": "learning_rate",
             "train_states": "train_states", "seed": "seed", "threads": "threads"}
    config = CoverNetConfig(**{key: getattr(args, attr) for attr, key in names.items() if getattr(args, attr)})
    metrics = fit_covernet(args.shards, config, out, root=args.root, progress=progress)
    val = metrics["val"]
    print(f"nbvtrain fit: scvp-net: validation sets of {val['predicted_size']:.2f} views against optimal "
          f"{val['optimal_size']:.2f}, precision {val['precision']:.3f}, recall {val['recall']:.3f} on "
          f"{plural(val['states'], 'state')}; {out / 'covernet.pt'} ({time.perf_counter() - started:.0f} s)")
    return 0


def cmd_predict(args: argparse.Namespace) -> int:
    """Print the NBV pose a checkpoint predicts for a grid (.npy) or a shard sample, as JSON."""
    from nbvtrain.networks.predict import GridError, Predictor, prediction_dict
    from nbvtrain.planners.released import released_ranker
    from nbvtrain.ranking.viewrank import is_ranker_file

    checkpoint = args.checkpoint or released_ranker()  # the default of every command: docs/released-models.md
    if is_ranker_file(checkpoint):
        return _predict_ranker(args, checkpoint)
    predictor = Predictor(checkpoint, device=args.device, k=args.k, radius=args.radius, tta=args.tta)
    taken, scans = None, None
    reads_scans = getattr(predictor.model, "reads_scans", False)
    if predictor.inputs == "points":
        grid, source, taken = _cloud_input(args, predictor)
    elif args.grid.suffix == ".npy" or not is_hdf5(args.grid):  # by its bytes: a grid, or no shard either
        try:
            grid, source = read_npy(args.grid, _not_a_grid(args.grid)), str(args.grid)
        except NpyError as error:
            raise ShardError(str(error)) from None
    else:
        with Shard(args.grid) as shard:
            if not 0 <= args.index < len(shard):
                raise ShardError(f"--index {args.index}: {args.grid} holds samples 0..{len(shard) - 1}")
            grid, source = shard.grids(args.index), f"{args.grid}[{args.index}]"
            if (predictor.view_units is not None or reads_scans) and shard.has("last_view"):
                from nbvtrain.networks.training_data import load_view_states

                state = load_view_states([args.grid], poses="nearest")[args.index]
                if reads_scans:  # where the sensor has been: the scanned candidate views
                    scans = shard["view_positions"][state]
                else:
                    taken = state
    if args.scanned is not None:
        taken = _scanned(args.scanned, predictor)
    if args.scanned_at is not None:
        if not reads_scans:
            raise ConfigError(f"--scanned-at: {predictor.name} reads no sensor positions (only nbvnet-4-3-scans "
                              "does); leave the flag out")
        scans = _positions(args.scanned_at)
    elif reads_scans and scans is None:
        raise ConfigError(f"{source}: {predictor.name} reads where the sensor has been: pass --scanned-at "
                          "'x,y,z;x,y,z' (sensor positions, object frame; 'none' when nothing was scanned); a shard "
                          "sample of a run gives them itself")
    try:
        predictions = predictor.predict(grid, taken, scans)
    except GridError as error:
        raise ShardError(f"{source}: {error}") from None
    if predictor.inputs == "points" or grid.ndim == 3:  # one cloud or one grid: one answer
        answer = prediction_dict(predictions[0], predictor, source, taken, scans)
    else:  # (B, 32, 32, 32): a list of B answers, in order
        answer = [prediction_dict(prediction, predictor, f"{source}[{index}]", taken, scans)
                  for index, prediction in enumerate(predictions)]
    print(json.dumps(answer, indent=2, allow_nan=False))
    return 0


def _not_a_grid(path: Path) -> str:
    """What ``predict`` says of a file that is neither a .npy grid nor an HDF5 file: what it is not,
    and what it is (no advice to delete it: it is no damaged shard)."""
    if path.suffix == ".npy" or not path.is_file():
        return NOT_NPY
    return (f"not a shard (.h5) or a .npy grid ({file_kind(path)}): give a grid saved with np.save (GRID.npy), or "
            "a shard nbvdata generate wrote")


def _predict_ranker(args: argparse.Namespace, path: Path) -> int:
    """``predict`` with a ranker: the candidate view it ranks first, as JSON, for a shard sample (its
    run's views and scans) or a .npy of one grid or (B, n, n, n) grids (the default scene's views,
    --scanned or --scanned-at; B grids: a list of B answers), each grid checked as a network's is."""
    from nbvdata.core.config import SimConfig
    from nbvdata.core.userarrays import GridError, check_grids
    from nbvdata.core.views import ViewSet, look_at_rotations, parse_view_indices, scanned_views, view_sphere
    from nbvtrain.ranking.viewrank import load_ranker

    ranker = load_ranker(path)
    for flag in ("tta", "radius"):
        if getattr(args, flag) not in (None, False):
            raise ConfigError(f"--{flag}: not an option of a ranker ({ranker.kind}); leave it out")
    if args.grid.suffix == ".npy" or not is_hdf5(args.grid):  # by its bytes: a grid, or no shard either
        try:
            grid, source = read_npy(args.grid, _not_a_grid(args.grid)), str(args.grid)
        except NpyError as error:
            raise ShardError(str(error)) from None
        config = SimConfig()
        views = view_sphere(config.views)
        positions = np.zeros((0, 3))
    else:
        from nbvtrain.networks.training_data import load_view_states

        with Shard(args.grid) as shard:
            if not 0 <= args.index < len(shard):
                raise ShardError(f"--index {args.index}: {args.grid} holds samples 0..{len(shard) - 1}")
            grid, source = shard.grids(args.index), f"{args.grid}[{args.index}]"
            config = from_dict(SimConfig, shard.info.config or {})
            view_positions = shard["view_positions"]
            has_runs = shard.has("last_view")
        views = ViewSet(view_positions, look_at_rotations(view_positions))
        positions = view_positions[load_view_states([args.grid], poses="nearest")[args.index]] if has_runs else \
            np.zeros((0, 3))
    ranker.check_scene(config, str(path))
    try:
        grids = check_grids(grid, config.scene_grid.size)
    except GridError as error:
        raise ShardError(f"{source}: {error}") from None
    if args.scanned is not None:
        try:
            positions = views.positions[parse_view_indices(args.scanned, len(views), "--scanned", "3,41,120")]
        except ValueError as error:
            raise ConfigError(f"{error} (the scene's candidate views)") from None
    if args.scanned_at is not None:
        positions = _positions(args.scanned_at)
    taken = scanned_views(positions, views.unit_positions)

    def answer(state: np.ndarray, where: str) -> dict:
        scores = np.where(taken, -np.inf, ranker.view_scores(state, positions, views, config))
        order = [int(v) for v in np.argsort(-scores, kind="stable") if np.isfinite(scores[v])][:5]
        view = order[0] if order else 0
        x, y, z, yaw, pitch, roll = views[view].xyzypr.tolist()
        return {"source": where, "ranker": str(path), "model": ranker.kind, "view": view,
                "scanned": np.flatnonzero(taken).tolist(), "position": [x, y, z], "yaw": yaw, "pitch": pitch,
                "roll": roll, "direction": views.unit_positions[view].tolist(),
                "runner_ups": [{"view": v, "score": float(scores[v])} for v in order]}

    answers = [answer(state, source if np.ndim(grid) == 3 else f"{source}[{index}]")
               for index, state in enumerate(grids)]
    print(json.dumps(answers[0] if np.ndim(grid) == 3 else answers, indent=2, allow_nan=False))
    return 0


def _cloud_input(args: argparse.Namespace, predictor) -> tuple[np.ndarray, str, np.ndarray | None]:
    """(cloud (M, 3), source, view state or None) for a point network: a cloud file (.npy, .ply,
    .pcd, .xyz: every scanned point, object frame, metres) or a shard sample's stored cloud and view
    state. ShardError for a shard without clouds, SensorDataError for a bad cloud file."""
    if args.grid.suffix not in (".h5", ".hdf5"):
        from nbvtrain.robot.sensordata import read_cloud

        return read_cloud(args.grid), str(args.grid), None
    with Shard(args.grid) as shard:
        if not 0 <= args.index < len(shard):
            raise ShardError(f"--index {args.index}: {args.grid} holds samples 0..{len(shard) - 1}")
        if not shard.has("points"):
            raise ShardError(f"{args.grid}: holds no point clouds, which {predictor.name} reads: give a cloud file "
                             "(.npy, .ply, .pcd, .xyz) or a shard made with --set state.points=N")
        cloud = shard.cloud(args.index)
        if not len(cloud):  # nothing scanned: the stored cloud is zeros, what the network was given
            cloud = np.zeros((1, 3), dtype=np.float32)
        from nbvdata.schema.shards import view_state

        states = view_state(shard["run"], shard["step"], shard["last_view"], len(shard["view_positions"]))
        return cloud, f"{args.grid}[{args.index}]", states[args.index]


def _positions(text: str) -> np.ndarray:
    """--scanned-at 'x,y,z;x,y,z' (or 'none') -> (S, 3) float64 sensor positions."""
    if text.strip().lower() == "none":
        return np.zeros((0, 3))
    try:
        rows = [[float(value) for value in part.split(",")] for part in text.replace(" ", "").split(";") if part]
    except ValueError:
        rows = []
    if not rows or any(len(row) != 3 for row in rows) or not np.isfinite(rows).all():
        raise ConfigError(f"--scanned-at {text!r}: give the sensor positions as x,y,z;x,y,z (object frame, metres; "
                          "only their directions from the object count), or 'none'")
    return np.array(rows)


def _scanned(text: str, predictor) -> np.ndarray:
    """--scanned 3,41,120 -> (V,) bool view state of a score network."""
    if predictor.view_units is None:
        raise ConfigError(f"--scanned: {predictor.name} is not a score network; it takes no view state")
    from nbvdata.core.views import parse_view_indices

    views = len(predictor.view_units)
    try:
        indices = parse_view_indices(text, views, "--scanned", "3,41,120")
    except ValueError as error:
        raise ConfigError(f"{error} (the network's candidate views)") from None
    taken = np.zeros(views, dtype=bool)
    taken[indices] = True
    return taken


def cmd_plan(args: argparse.Namespace) -> int:
    """Print the NBV for a robot's scans or OctoMap, in its world frame, as JSON."""
    from nbvdata.core.config import SimConfig
    from nbvtrain.robot.plan import PlanError, parse_vector, plan, render_plan

    for flag, path, suffix in (("--save-grid", args.save_grid, ".npy"), ("--png", args.png, ".png")):
        if path is not None and path.suffix.lower() != suffix:
            raise PlanError(f"{flag} {path}: name a {suffix} file")
    config = load_config(SimConfig, args.config, args.overrides)
    result = plan(parse_vector(args.center, "--center"), scans=args.scans, octomap=args.octomap, size=args.size,
                  up=args.up, checkpoint=args.checkpoint, config=config, max_range=args.max_range, device=args.device,
                  tta=args.tta, spread=args.spread)
    answer = result.to_dict()
    if result.octomap is not None and not result.octomap["exact"]:
        print(f"nbvtrain plan: note: the map's voxels ({result.octomap['resolution']:g} m) are not the grid's "
              f"({answer['grid']['voxel']:.4g} m, corner on a key boundary): each grid voxel took the map's leaf at "
              "its centre", file=sys.stderr)
    text = json.dumps(answer, indent=2, allow_nan=False)
    for path, write in ((args.out, lambda p: p.write_text(text + "\n")),
                        (args.save_grid, lambda p: np.save(p, result.grid)),
                        (args.png, lambda p: render_plan(result, p))):
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            write(path)
    print(text)
    return 0


def cmd_baselines(args: argparse.Namespace) -> int:
    """Score the mean-direction, nearest-neighbour and farthest-view predictors on a split, as fit would make it."""
    from nbvtrain.networks.baselines import BASELINES, Skipped
    from nbvtrain.networks.metrics import format_ratio
    from nbvtrain.networks.training_data import load_shards, split_indices

    data = load_shards(shard_files(args.shards), args.memory_limit_gb, args.mixed_scenes)
    try:
        train_idx, val_idx, split = split_indices(data, args.split, args.val_fraction, args.seed)
        print(f"{len(train_idx)} training and {plural(len(val_idx), 'validation sample')} ({split['kind']} split, "
              f"seed {args.seed})")
        print(f"{'predictor':20s} {'val MSE':>8s} {'val MAE':>8s} {'angle':>8s} {'gain ratio':>10s} {'invalid':>8s} "
              f"{'seconds':>8s}")
        for name, baseline in BASELINES.items():
            started = time.perf_counter()
            try:
                scores = baseline(data, train_idx, val_idx)
            except Skipped as reason:
                print(f"{name:20s} skipped: {reason}")
                continue
            print(f"{name:20s} {scores['mse']:8.4f} {scores['mae']:8.4f} {scores['angle_deg']:7.1f}d "
                  f"{format_ratio(scores['gain_ratio']):>10s} {format_ratio(scores['invalid_share']):>8s} "
                  f"{time.perf_counter() - started:8.1f}")
    finally:
        data.close()
    return 0


def _manifest_part(args: argparse.Namespace, purpose: str) -> tuple[list, dict] | None:
    """evaluate's and benchmark's ``--manifest M --part P``: (the mesh sources of that part of its
    split, found under --meshes; the selection's settings), or None without --manifest (where a
    --part alone is refused). ``purpose``: what the part is for, in the message that asks for it."""
    from nbvdata.simulation.sources import part_sources

    if args.manifest is None:
        if args.part is not None:
            raise ConfigError(f"--part {args.part} needs --manifest manifests/NAME-X.Y.Z.json, the published version "
                              "whose mesh split it names")
        return None
    if args.part is None:
        raise ConfigError(f"--manifest needs --part val, test or train: the part of its mesh split to {purpose}")
    return part_sources(args.manifest, args.part, args.meshes)


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Reconstruct unseen objects in closed loop with each planner; coverage.csv, summary, plots."""
    from nbvdata.core.config import SimConfig
    from nbvdata.core.views import view_sphere
    from nbvdata.simulation.mesh import MeshError
    from nbvdata.simulation.sources import mesh_sources
    from nbvtrain.evaluation.evaluate import evaluate, settings_dict, write_outputs
    from nbvtrain.planners import build_planners

    names = _planner_names(args)
    config = load_config(SimConfig, args.config, args.overrides)
    if args.rerun is not None:
        try:
            import nbvdata.view.rerun  # noqa: F401  (missing: said before any reconstruction)
        except ImportError as error:
            raise ConfigError(f"--rerun: {error}") from None
    chosen = _manifest_part(args, "evaluate")
    if chosen is not None:
        (sources, selection), failures = chosen, []
    else:
        selection = {}
        if args.meshes is None:
            raise ConfigError("no meshes given: --meshes DIR (a folder, one mesh file or a .txt list), or --manifest "
                              "manifests/NAME-X.Y.Z.json --part val --meshes ROOT")
        try:
            sources, failures = mesh_sources(args.meshes)
        except MeshError as error:
            raise ConfigError(str(error)) from None
    weights = _numbers(args.hybrid_weight, "--hybrid-weight")
    checkpoints = _checkpoints(args)
    if args.spread is not None and args.no_stall:
        raise ConfigError("--spread never repeats a view already: drop --no-stall")
    planners, skipped = build_planners(names, config, view_sphere(config.views), checkpoints, args.no_stall, args.tta,
                                       weights, args.hybrid_stride, args.spread)
    for message in skipped:
        print(f"nbvtrain evaluate: {message}", file=sys.stderr)
    if not planners:
        raise ConfigError("no planner left to run: give checkpoints or add infogain, oracle, random or farthest to "
                          "--planners")
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    workers = args.workers or os.cpu_count() or 1
    report = evaluate(sources, planners, config, args.scans, args.random_starts, args.seed, progress, workers,
                      args.floors, args.rerun)
    report.failures = failures + report.failures
    learned = {p.name: p.checkpoints for p in planners if hasattr(p, "checkpoints")}
    recorded = {name: files[0] if len(files) == 1 else files for name, files in learned.items()}  # or an ensemble
    settings = settings_dict(config, meshes=args.meshes, **selection, planners=[p.name for p in planners],
                             scans=args.scans, random_starts=args.random_starts, seed=args.seed, checkpoints=recorded,
                             no_stall=args.no_stall, tta=args.tta, floors=args.floors,
                             **({"spread": args.spread} if args.spread is not None else {}),
                             **({"hybrid_weights": weights, "hybrid_stride": args.hybrid_stride}
                                if "hybrid" in names else {}))
    write_outputs(report, args.out, [p.name for p in planners], skipped, settings)
    runs = len({(r["mesh"], r["planner"], r["start"]) for r in report.rows})
    print(f"nbvtrain evaluate: {plural(runs, 'reconstruction')} in {report.seconds:.1f} s; wrote "
          f"{args.out / 'coverage.csv'}, {args.out / 'summary.md'} and {args.out / 'plots'}/"
          + (f"; Rerun recordings in {args.rerun}/ (open one with: rerun {args.rerun}/MESH.rrd)"
             if args.rerun is not None else ""))
    for name, reason in report.failures:
        print(f"nbvtrain evaluate: failed: {name}: {reason}", file=sys.stderr)
    return 1 if report.failures else 0


def cmd_benchmark(args: argparse.Namespace) -> int:
    """Run a protocol of the field on a corpus of objects; tables, statistics and plots."""
    from nbvdata.core.views import view_sphere
    from nbvdata.simulation.mesh import MeshError
    from nbvdata.simulation.sources import mesh_sources
    from nbvtrain.evaluation.benchmark import BENCH_MESHES, benchmark, load_protocol, protocol_config, protocol_for
    from nbvtrain.evaluation.benchmark_report import write_benchmark
    from nbvtrain.evaluation.evaluate import settings_dict
    from nbvtrain.planners import CoverPlanner, TravelPlanner, build_planners, robot_radius

    protocol = load_protocol(args.protocol)
    weights = _numbers(args.travel_weight, "--travel-weight") if args.travel_weight is not None else []
    if not all(math.isfinite(weight) and weight >= 0 for weight in weights):
        raise ConfigError(f"--travel-weight {args.travel_weight}: each weight must be a finite number >= 0")
    config = protocol_config(protocol, args.config, args.overrides)
    names = _planner_names(args)
    references = [name.strip() for name in args.reference.split(",") if name.strip()]
    missing = [name for name in references if name not in names]
    if missing or not references:
        raise ConfigError(f"--reference {args.reference}: not among --planners ({','.join(names)}): add it, or compare "
                          "against one of them")
    meshes = args.meshes if args.meshes is not None else BENCH_MESHES
    chosen = _manifest_part(args, "run on")
    if chosen is not None:
        (sources, _), failures = chosen, []
        meshes = f"{args.manifest} --part {args.part}"
    else:
        if not meshes.exists():
            raise ConfigError(f"--meshes {meshes}: no such folder (the default is the bench corpus, "
                              "../shared/meshes/bench beside the checkout): pass --meshes DIR")
        try:
            sources, failures = mesh_sources(meshes)
        except MeshError as error:
            raise ConfigError(str(error)) from None
    if not sources:
        raise ConfigError(f"--meshes {meshes}: no mesh files in it")
    sources = sources[:args.limit] if args.limit else sources
    checkpoints = _checkpoints(args)
    planners, skipped = build_planners(names, config, view_sphere(config.views), checkpoints,
                                       foreign_views=protocol.snap, views_fix=protocol_for)
    for message in skipped:
        print(f"nbvtrain benchmark: {message}", file=sys.stderr)
    radius = robot_radius(config)
    planners += [TravelPlanner(planner, weight, radius) if hasattr(planner, "candidate_scores") else planner.travel(weight)
                 for weight in weights for planner in list(planners)
                 if hasattr(planner, "candidate_scores") or isinstance(planner, CoverPlanner)]
    skipped_references = [name for name in references if name not in {planner.name for planner in planners}]
    if skipped_references:
        raise ConfigError(f"--reference {','.join(skipped_references)}: that planner was skipped (see above): pass its "
                          "checkpoint or another --reference")
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    workers = args.workers or os.cpu_count() or 1
    report = benchmark(sources, planners, config, protocol, args.starts, args.seed, workers, progress, args.rerun)
    report.failures = failures + report.failures
    settings = {"protocol": to_dict(protocol)} | settings_dict(
        config, meshes=meshes, planners=[p.name for p in planners], starts=args.starts, seed=args.seed,
        reference=args.reference, limit=args.limit, travel_weights=weights,
        checkpoints={name: [str(p) for p in paths] if isinstance(paths, list) else (str(paths) if paths else None)
                     for name, paths in checkpoints.items()})
    write_benchmark(report, args.out, references, args.seed, settings)
    runs = len({(r["mesh"], r["planner"], r["start"]) for r in report.rows})
    print(f"nbvtrain benchmark: protocol {protocol.name}, {plural(runs, 'reconstruction')} of "
          f"{plural(len({r['mesh'] for r in report.rows}), 'object')} in {report.seconds:.1f} s; wrote "
          f"{args.out / 'benchmark.md'}, per_object.csv, coverage.csv and {args.out / 'plots'}/")
    for name, reason in report.failures:
        print(f"nbvtrain benchmark: failed: {name}: {reason}", file=sys.stderr)
    return 1 if report.failures else 0


def _planner_names(args: argparse.Namespace) -> list[str]:
    """evaluate's and benchmark's ``--planners``: the names given (default: the registry's default list),
    each a registered planner or a policy module:function; ConfigError otherwise."""
    from nbvtrain.planners import PLANNERS, default_planners

    given = args.planners if args.planners is not None else ",".join(default_planners())
    names = [name.strip() for name in given.split(",") if name.strip()]
    if not names or any(name not in PLANNERS and ":" not in name for name in names):
        raise ConfigError(f"--planners {given!r}: choose from {','.join(PLANNERS)}, or a policy module:function")
    return names


def _checkpoints(args: argparse.Namespace) -> dict:
    """evaluate's and benchmark's model flags as ``build_planners`` takes them: task -> file(s), None
    for the released one."""
    return {"scores": _checkpoint_list(args.score_checkpoint, "--score-checkpoint"), "regression": args.checkpoint,
            "classification": args.class_checkpoint, "ranker": _checkpoint_list(args.ranker, "--ranker"),
            "cover": args.cover_model, "scvp-net": args.scvp_checkpoint, "surface": args.surface_prior}


def _checkpoint_list(text: str | None, flag: str) -> list[Path] | None:
    """``A.pt,B.pt`` -> [A.pt, B.pt]; None stays None (the released model)."""
    if text is None:
        return None
    paths = [Path(part.strip()) for part in text.split(",") if part.strip()]
    if not paths:
        raise ConfigError(f"{flag} {text!r}: name one checkpoint, or several separated by commas (an ensemble)")
    return paths


def _numbers(text: str, flag: str) -> list[float]:
    """``0.5,1,2`` -> [0.5, 1.0, 2.0]."""
    try:
        numbers = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        numbers = []
    if not numbers:
        raise ConfigError(f"{flag} {text!r}: expected comma-separated numbers, e.g. {flag} 0.5,1,2")
    return numbers


def cmd_release(args: argparse.Namespace) -> int:
    """Write the released models (float16 weights), their reference answers and model card."""
    from nbvtrain.release import release

    runs = {task: folder for task, folder in (("scores", args.scores), ("regression", args.regression),
                                              ("viewrank", args.viewrank)) if folder}
    if not runs:
        raise ConfigError("nothing to release: give --scores RUN, --regression RUN and/or --viewrank RUN (run folders of "
                          "nbvtrain fit, or checkpoint files of them)")
    notes = None
    if args.notes is not None:
        try:
            notes = args.notes.read_text()
        except (OSError, UnicodeDecodeError) as error:
            raise ConfigError(f"--notes {args.notes}: cannot read it ({error}): pass a markdown file") from None
    written, removed = release(runs, args.evaluation, args.out, notes)
    for path in written:
        print(f"nbvtrain release: wrote {path}")
    for path in removed:
        print(f"nbvtrain release: removed {path}, the model it replaces")
    return 0
