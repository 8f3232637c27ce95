"""The ``nbvtrain`` command line: train NBV networks on shards, predict NBV poses, plan the NBV
from a robot's scans or OctoMap, score the baselines, evaluate planners in closed-loop
reconstructions and run the field's benchmark protocols.

Expected user errors (a bad setting, a missing or broken shard, checkpoint, cloud or map) print one line
naming the fix and exit with status 2; Ctrl-C during ``fit`` saves a checkpoint first and
exits with 130.
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

from nbvdata.commandline import (Integer, Number, Parser, exit_quietly_when_stdout_closes, fraction, non_negative_float,
                                  non_negative_int, positive_float, positive_int, run_command)
from nbvdata.config import ConfigError, from_dict, load_config, to_dict
from nbvdata.shards import Shard, ShardError, shard_files
from nbvdata.text import plural
from nbvdata.userarrays import NOT_NPY, NpyError, file_kind, is_hdf5, read_npy
from nbvtrain import __version__

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
    for flag, of in (("width", "scvp-net"), ("train_states", "scvp-net"), ("features", "viewrank-gbm|viewrank-mlp"),
                     ("label", "viewrank-gbm"), ("surface_prior", "viewrank-gbm|viewrank-mlp")):
        if getattr(args, flag, None) is not None:
            raise ConfigError(f"--{flag.replace('_', '-')}: an option of --model {of} only; leave it out")
    from nbvtrain.config import TrainConfig
    from nbvtrain.train import Interrupted, fit, load_run_config

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


RANKERS = ("viewrank-gbm", "viewrank-mlp")  # nbvtrain.viewrank.KINDS, without importing it for --help
RANKER_FLAGS = {"rays": "rays", "sample": "sample", "seed": "seed", "trees": "trees", "lr": "learning_rate",
                "epochs": "epochs", "threads": "threads", "features": "features", "label": "label"}


def _fit_ranker(args: argparse.Namespace) -> int:
    """``fit --model viewrank-*``: a ranker of candidate views on manifests or shard folders."""
    from nbvtrain.rankfit import DEFAULT_CACHE, describe, fit_ranker
    from nbvtrain.viewrank import RankerConfig

    for flag in ("resume", "add_train", "init", "augment", "dropout", "dropout_from", "score_loss", "regression_loss",
                 "batch_size", "lr_schedule", "near_best", "mixed_scenes", "config", "width", "train_states"):
        if getattr(args, flag, None) not in (None, False, []):
            raise ConfigError(f"--{flag.replace('_', '-')}: not an option of a ranker ({args.model}); leave it out")
    if args.split == "random":
        raise ConfigError("--split random: a ranker is validated on whole meshes (the mesh split); leave --split out")
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


COVER_MODELS = ("cover-gbm", "scvp-net")  # nbvtrain.covermodel, nbvtrain.covernet
SURFACE_MODEL = "surface-gbm"  # nbvtrain.surfaceprior


def _fit_surface(args: argparse.Namespace) -> int:
    """``fit --model surface-gbm``: a surface prior on shards with the meshes' surface voxels."""
    from nbvtrain.surfaceprior import SurfacePriorConfig, fit_surface_prior

    allowed = ("seed", "trees", "lr", "threads", "workers")
    for flag in ("resume", "add_train", "init", "augment", "dropout", "dropout_from", "score_loss", "regression_loss",
                 "lr_schedule", "near_best", "mixed_scenes", "config", "rays", "sample", "epochs", "batch_size",
                 "width", "train_states", "feature_cache", "features", "label", "surface_prior"):
        if flag not in allowed and getattr(args, flag, None) not in (None, False, []):
            raise ConfigError(f"--{flag.replace('_', '-')}: not an option of {args.model}; leave it out")
    if args.split == "random":
        raise ConfigError(f"--split random: {args.model} is validated on whole meshes (the mesh split); leave --split out")
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
    allowed = {"cover-gbm": ("rays", "sample", "seed", "trees", "lr", "threads", "workers", "feature_cache"),
               "scvp-net": ("seed", "epochs", "batch_size", "lr", "threads", "width", "train_states")}[args.model]
    for flag in ("resume", "add_train", "init", "augment", "dropout", "dropout_from", "score_loss", "regression_loss",
                 "lr_schedule", "near_best", "mixed_scenes", "config", "rays", "sample", "trees", "epochs",
                 "batch_size", "width", "train_states", "feature_cache", "features", "label", "surface_prior"):
        if flag not in allowed and getattr(args, flag, None) not in (None, False, []):
            raise ConfigError(f"--{flag.replace('_', '-')}: not an option of {args.model}; leave it out")
    if args.split == "random":
        raise ConfigError(f"--split random: {args.model} is validated on whole meshes (the mesh split); leave --split out")
    out = args.out or Path("runs") / args.model
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    started = time.perf_counter()
    if args.model == "cover-gbm":
        from nbvtrain.covermodel import CoverModelConfig, fit_cover_model
        from nbvtrain.rankfit import DEFAULT_CACHE

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
    from nbvtrain.covernet import CoverNetConfig, fit_covernet

    names = {"width": "width", "epochs": "epochs", "batch_size": "batch", "lr": "learning_rate",
             "train_states": "train_states", "seed": "seed", "threads": "threads"}
    config = CoverNetConfig(**{key: getattr(args, attr) for attr, key in names.items() if getattr(args, attr)})
    metrics = fit_covernet(args.shards, config, out, root=args.root, progress=progress)
    val = metrics["val"]
    print(f"nbvtrain fit: scvp-net: validation sets of {val['predicted_size']:.2f} views against optimal "
          f"{val['optimal_size']:.2f}, precision {val['precision']:.3f}, recall {val['recall']:.3f} on "
          f"{plural(val['states'], 'state')}; {out / 'covernet.pt'} ({time.perf_counter() - started:.0f} s)")
    return 0


def _cover_model_flags(parser: argparse.ArgumentParser) -> None:
    """evaluate's and benchmark's files of the cover planners (``nbvtrain.planners.CoverPlanner``)."""
    parser.add_argument("--cover-model", type=Path, help="the cover planner's model: a cover.json of nbvtrain fit "
                        "--model cover-gbm (docs/setcover.md)")
    parser.add_argument("--scvp-checkpoint", type=Path, help="the scvp-net planner's network: a covernet.pt of nbvtrain "
                        "fit --model scvp-net (docs/setcover.md)")


def _names(text: str) -> tuple[str, ...]:
    """'base,metrics' -> ('base', 'metrics')."""
    names = tuple(part.strip() for part in text.split(",") if part.strip())
    if not names:
        raise argparse.ArgumentTypeError(f"{text!r}: name at least one group or column, comma-separated")
    return names


def _rays(text: str) -> tuple[int, int]:
    """'16x12' -> (16, 12)."""
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give WIDTHxHEIGHT rays per view, e.g. 16x12") from None
    if width < 1 or height < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: each of WIDTH and HEIGHT must be >= 1")
    return width, height


def cmd_predict(args: argparse.Namespace) -> int:
    """Print the NBV pose a checkpoint predicts for a grid (.npy) or a shard sample, as JSON."""
    from nbvtrain.predict import GridError, Predictor, prediction_dict

    from nbvtrain.release import released_ranker
    from nbvtrain.viewrank import is_ranker_file

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
                from nbvtrain.training_data import load_view_states

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
    from nbvdata.config import SimConfig
    from nbvdata.userarrays import GridError, check_grids
    from nbvdata.views import ViewSet, look_at_rotations, parse_view_indices, scanned_views, view_sphere
    from nbvtrain.viewrank import load_ranker

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
        from nbvtrain.training_data import load_view_states

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
        from nbvtrain.sensordata import read_cloud

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
        from nbvdata.shards import view_state

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
    from nbvdata.views import parse_view_indices

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
    from nbvdata.config import SimConfig
    from nbvtrain.plan import PlanError, parse_vector, plan, render_plan

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
    from nbvtrain.baselines import BASELINES, Skipped
    from nbvtrain.training_data import load_shards, split_indices
    from nbvtrain.metrics import format_ratio

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
    from nbvdata.sources import part_sources

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
    from nbvdata.config import SimConfig
    from nbvdata.sources import mesh_sources
    from nbvdata.mesh import MeshError
    from nbvdata.views import view_sphere
    from nbvtrain.evaluate import evaluate, settings_dict, write_outputs
    from nbvtrain.planners import build_planners

    names = _planner_names(args)
    config = load_config(SimConfig, args.config, args.overrides)
    if args.rerun is not None:
        try:
            import nbvdata.rerun  # noqa: F401  (missing: said before any reconstruction)
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
    from nbvdata.mesh import MeshError
    from nbvdata.sources import mesh_sources
    from nbvdata.views import view_sphere
    from nbvtrain.benchmark import BENCH_MESHES, benchmark, load_protocol, protocol_config, protocol_for
    from nbvtrain.benchmark_report import write_benchmark
    from nbvtrain.evaluate import settings_dict
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
            "cover": args.cover_model, "scvp-net": args.scvp_checkpoint}


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


def build_parser() -> Parser:
    from nbvtrain.release import TASKS, released_files

    # what commands use without a checkpoint: the package's released network of each task
    files = released_files()
    released = {task: Path(files[task]).stem if task in files else "none released" for task in TASKS}

    summary = " ".join(__doc__.split("\n\n")[0].replace("``", "").split())  # the first paragraph, whole
    parser = Parser(prog="nbvtrain", description=summary)
    parser.add_argument("--version", action="version", version=f"nbvtrain {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_fit(sub, released)
    _add_predict(sub, released)
    _add_plan(sub, released)
    _add_baselines(sub, released)
    _add_evaluate(sub, released)
    _add_benchmark(sub, released)
    _add_release(sub, released)
    return parser


def _add_fit(sub, released: dict[str, str]) -> None:
    """``fit``: its options."""
    from nbvtrain.models import MODELS

    fit = sub.add_parser("fit", help="train a network on shards (files or folders)")
    fit.add_argument("shards", type=Path, nargs="*", help="shard files or folders of shards, or one published "
                     "version's manifest (manifests/NAME-X.Y.Z.json: verified, then trained on with its split)")
    fit.add_argument("--root", type=Path, help="with a manifest: the folder holding its shards (default: the "
                     "one it records)")
    fit.add_argument("--add-train", type=Path, action="append", metavar="SHARDS", help="with a manifest: more "
                     "shards (a file or folder; repeatable) for its training part, e.g. a DAgger round on its training "
                     "meshes (nbvdata generate --manifest M --part train --policy CKPT); refused when they hold a mesh "
                     "of its validation or test part")
    fit.add_argument("--init", metavar="CHECKPOINT", help="start from this checkpoint's weights (same --model) "
                     "instead of fresh ones: fine-tuning, e.g. on a DAgger round; a fresh optimiser (init)")
    fit.add_argument("--config", type=Path, help="YAML file of training settings (default: the paper's, which "
                     "configs/train.yaml lists)")
    fit.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                     help="override one setting, e.g. --set dropout=0.3 (repeatable)")
    fit.add_argument("--model", choices=list(MODELS) + list(RANKERS) + list(COVER_MODELS) + [SURFACE_MODEL],
                     help="network (default "
                     "nbvnet-4-5), or a ranker of candidate views from per-view features: viewrank-gbm (LightGBM "
                     "lambdarank) or viewrank-mlp (a small torch scorer), trained on manifests' mesh splits "
                     "(docs/viewrank.md); or a set-cover model on shards with covers: cover-gbm (each view's membership "
                     "from the ranker's features, any view set) or scvp-net (SCVP's network, one view set) "
                     "(docs/setcover.md); or surface-gbm, a prior of the surface hidden in a partial grid, on shards "
                     "made with state.surface (docs/viewrank.md)")
    fit.add_argument("--epochs", type=positive_int, help="total epochs (default 600)")
    fit.add_argument("--batch-size", type=positive_int, help="samples per step (default 250)")
    fit.add_argument("--lr", type=positive_float, help="Adam learning rate (default 1e-4)")
    fit.add_argument("--lr-schedule", choices=["constant", "cosine"], help="constant (paper, default) or cosine "
                     "decay to 0 over the epochs")
    fit.add_argument("--score-loss", choices=["listwise", "regression", "argmax"], help="score networks "
                     "(nbvscore-*): the loss over every candidate view's gain (default listwise)")
    fit.add_argument("--regression-loss", choices=["label", "near-best"], help="regression networks: squared "
                     "error to the label (paper, default) or to the nearest near-best view")
    fit.add_argument("--near-best", type=Number(0.0, 1.0, low_open=True), help="near-best loss: a view "
                     "within this share of the best gain is a target (default 0.9)")
    fit.add_argument("--dropout", type=fraction, help="dropout probability (default 0.5)")
    fit.add_argument("--dropout-from", help="dropout from this layer to the end: conv1..conv4, fc, fc2.., none "
                     "(default conv3)")
    fit.add_argument("--split", choices=["random", "mesh"], help="random samples (paper) or whole meshes held out; "
                     "with a manifest, its split of that kind")
    fit.add_argument("--val-fraction", type=fraction, help="share held out for validation (default 0.2)")
    fit.add_argument("--augment", action=argparse.BooleanOptionalAction, default=None,
                     help="rotate grids and targets by random quarter turns about z")
    fit.add_argument("--seed", type=non_negative_int, help="seed of split, weights, batches, dropout (default 0)")
    fit.add_argument("--device", choices=["auto", "cpu", "cuda"], help="default auto")
    fit.add_argument("--threads", type=non_negative_int, help="torch CPU threads (default: one per core)")
    fit.add_argument("--mixed-scenes", action="store_true", default=None, help="train on shards made in different "
                     "scenes (other views, sensor, grid, ...; refused by default): the checkpoint records a mixed "
                     "scene")
    fit.add_argument("--target", choices=["valid", "all"], default="valid", help="rankers: learn the gains of views "
                     "that pass the overlap rule (valid, the ground truth's, default) or of every view (all)")
    fit.add_argument("--rays", type=_rays, help="rankers: rays per view of the features' bundle, WIDTHxHEIGHT "
                     "(default 16x12)")
    fit.add_argument("--sample", type=non_negative_int, help="rankers: training rows per state at most (viewrank default 64, cover-gbm 0; "
                     "0 = every unscanned view)")
    fit.add_argument("--trees", type=positive_int, help="viewrank-gbm: boosting rounds at most (default 600)")
    fit.add_argument("--features", type=_names, help="rankers: the columns read, groups (base, metrics, shadow, "
                     "surface) or column names, comma-separated (default base: the first ranker's; docs/viewrank.md)")
    fit.add_argument("--surface-prior", type=Path, help="rankers of --features ...,surface: the surface prior "
                     "(surface.json of --model surface-gbm) whose expected surface they read; the ranker carries it")
    fit.add_argument("--label", choices=["graded", "scone", "vin"], help="viewrank-gbm: lambdarank on graded gains "
                     "(default), SCONE's L1 on gain / the state's mean, or VIN-NBV's stage-normalised ordinal bins")
    fit.add_argument("--workers", type=positive_int, default=2, help="rankers: processes computing the features "
                     "(default 2)")
    fit.add_argument("--feature-cache", type=Path, help="rankers: folder keeping each shard's features for the next "
                     "fit (default runs/viewrank-features; 'none': keep none)")
    fit.add_argument("--width", type=positive_int, help="scvp-net: channels of its stem (default 32, SCVP's)")
    fit.add_argument("--train-states", type=positive_int, help="scvp-net: train on at most this many states (a seeded "
                     "choice; default all)")
    fit.add_argument("--out", type=Path, help="run folder (default runs/MODEL)")
    fit.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    fit.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                     help="show a progress bar (default: on a terminal)")
    fit.set_defaults(func=cmd_fit)


def _add_predict(sub, released: dict[str, str]) -> None:
    """``predict``: its options."""
    predict = sub.add_parser("predict", help="the NBV pose a checkpoint predicts for a grid or cloud, as JSON")
    predict.add_argument("grid", type=Path, help="a .npy of one (32, 32, 32) grid or of (B, 32, 32, 32) grids "
                         "(probabilities, 0.5 = unknown; B grids print a JSON list of B answers), or a shard; for a "
                         "point network (nbvscore-pc) a cloud (.npy (M, 3), .ply, .pcd, .xyz: every scanned point, "
                         "object frame, metres) or a shard made with state.points")
    predict.add_argument("--index", type=non_negative_int, default=0, help="sample of the shard (default 0)")
    predict.add_argument("--checkpoint", type=Path, help="a checkpoint of nbvtrain fit (best.pt) or a ranker "
                         f"(viewrank.json or .pt); default: the released ranker, {released['viewrank']} (every "
                         "command's defaults: docs/released-models.md)")
    predict.add_argument("--scanned", help="rankers and score networks: candidate views already scanned, e.g. 3,41,120 (default: "
                         "from the shard's run for a shard sample, none for a .npy grid)")
    predict.add_argument("--scanned-at", metavar="'X,Y,Z;...'", help="rankers and nbvnet-4-3-scans: the sensor positions "
                         "scanned so far, object frame, e.g. '0.4,0,0;0,0,0.4', or 'none' (required for a .npy grid; "
                         "default for a shard sample: its run's scanned views)")
    predict.add_argument("--k", type=positive_float, default=1.0, help="scale of the position beyond the view sphere "
                         "(paper: 2.5 for its 1 m robot scene)")
    predict.add_argument("--radius", type=positive_float, help="view sphere radius, metres (default: the training "
                         "data's)")
    predict.add_argument("--tta", action="store_true", help="quarter-turn test-time averaging (exact for regression "
                         "networks and nbvscore-3; refused for the others)")
    predict.add_argument("--device", default="cpu", help="torch device (default cpu)")
    predict.set_defaults(func=cmd_predict)


def _add_plan(sub, released: dict[str, str]) -> None:
    """``plan``: its options."""
    plan = sub.add_parser("plan", help="the NBV for a robot's scans or OctoMap, in its world frame, as JSON",
                          description="The next-best-view for an object in a robot's world frame, from its scans "
                          "(clouds with sensor poses) or an OctoMap: the data is cropped to the object's box, "
                          "scaled to the training scene (k = --size / mesh.object_size) and the network's answer "
                          "is mapped back to the world frame. README: Using a trained network on your robot.")
    source = plan.add_mutually_exclusive_group(required=True)
    source.add_argument("--scans", type=Path, help="YAML list of scans, each {cloud: PATH, pose: 4x4 camera-to-world} "
                        "or {cloud: PATH, position: [x, y, z], quaternion_xyzw: [x, y, z, w]}; clouds (.ply, .pcd, "
                        ".xyz, .npy) hold world-frame points, paths relative to the file")
    source.add_argument("--octomap", type=Path, help="an OctoMap in the world frame (.bt or .ot)")
    plan.add_argument("--center", required=True, help="the object's centre x,y,z, world frame, metres "
                      "(write --center=-1,2,3 when it starts with a minus)")
    plan.add_argument("--size", type=positive_float, help="the object's largest side, metres (default: the training "
                      "scene's mesh.object_size, 0.136); the grid's cube and the view radius scale with it")
    plan.add_argument("--up", default="z", help="the world's vertical: x, y, z, -x, -y, -z or a vector a,b,c "
                      "(default z)")
    plan.add_argument("--checkpoint", type=Path, help="a checkpoint of nbvtrain fit: a candidate-score, regression or "
                      "classification network, or a ranker (viewrank.json or .pt; default: the released ranker, "
                      f"{released['viewrank']}, ahead on the validation objects; the released score network, "
                      f"{released['scores']}, is nbvtrain/released/{released['scores']}.pt); or a set-cover model "
                      "(cover.json of --model cover-gbm, covernet.pt of --model scvp-net): then the answer also holds "
                      "plan, every planned view in tour order, and plan_path (docs/setcover.md)")
    plan.add_argument("--max-range", type=positive_float, help="with --scans: metres from the sensor beyond which a "
                      "point marks nothing occupied and carves free space to that range (default sensor.far x k)")
    plan.add_argument("--config", type=Path, help="YAML of the training data's scene, as for nbvdata (default: "
                      "the default scene)")
    plan.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                      help="override one scene setting, e.g. --set mesh.object_size=0.24")
    plan.add_argument("--out", type=Path, help="also write the JSON to this file")
    plan.add_argument("--save-grid", type=Path, help="write the grid the network saw (.npy, 32^3 probabilities, "
                      "0.5 = unknown, object frame)")
    plan.add_argument("--png", type=Path, help="write a picture of that grid with the scans and the chosen view")
    plan.add_argument("--tta", action="store_true", help="quarter-turn test-time averaging (exact for regression "
                      "networks and nbvscore-3; refused for the others)")
    plan.add_argument("--spread", type=non_negative_float, metavar="W", help="with --scans, a regression or "
                      "classification network: the candidate view with the highest cos(answer, view) - W cos(view, its "
                      "nearest scan), as nbvtrain evaluate --spread (off: the network's answer as it is)")
    plan.add_argument("--device", default="cpu", help="torch device (default cpu)")
    plan.set_defaults(func=cmd_plan)


def _add_baselines(sub, released: dict[str, str]) -> None:
    """``baselines``: its options."""
    baselines = sub.add_parser("baselines", help="mean-direction, nearest-neighbour and farthest-view scores on a split")
    baselines.add_argument("shards", type=Path, nargs="+", help="shard files or folders of shards")
    baselines.add_argument("--split", choices=["random", "mesh"], default="random", help="random samples (paper, "
                           "default) or whole meshes held out, as nbvtrain fit --split")
    baselines.add_argument("--val-fraction", type=fraction, default=0.2, help="share held out for validation "
                           "(default 0.2)")
    baselines.add_argument("--seed", type=non_negative_int, default=0, help="seed of the split, as nbvtrain fit --seed "
                           "(default 0)")
    baselines.add_argument("--memory-limit-gb", type=non_negative_float, default=8.0, help="grids in memory up to this "
                           "size, else read from the shards as needed (default 8)")
    baselines.add_argument("--mixed-scenes", action="store_true", help="score shards made in different scenes "
                           "together (refused by default, as by fit)")
    baselines.set_defaults(func=cmd_baselines)


def _add_evaluate(sub, released: dict[str, str]) -> None:
    """``evaluate``: its options."""
    evaluate = sub.add_parser("evaluate", help="closed-loop reconstructions of unseen objects with each planner")
    evaluate.add_argument("--meshes", type=Path, help="folder of meshes, one mesh file, or a .txt list; with "
                          "--manifest the folder the version's meshes lie in or below (e.g. ../shared/meshes)")
    evaluate.add_argument("--manifest", type=Path, help="a published version (manifests/NAME-X.Y.Z.json): evaluate "
                          "exactly the meshes of --part of its mesh split, found under --meshes by name and sha256")
    evaluate.add_argument("--part", help="with --manifest: val (choosing anything), test or train")
    _cover_model_flags(evaluate)
    evaluate.add_argument("--ranker", help="the viewrank planner's model: a ranker file of nbvtrain fit --model "
                          "viewrank-gbm|viewrank-mlp (default: the released one); several, comma-separated, are "
                          "compared as viewrank-FOLDER each")
    evaluate.add_argument("--score-checkpoint", help="candidate-score checkpoint (a run of an nbvscore-* model; "
                          f"default: the released one, {released['scores']}), or several separated by commas: an "
                          "ensemble (mean of their standardised scores)")
    evaluate.add_argument("--tta", action="store_true", help="quarter-turn test-time averaging for every learned "
                          "planner (exact for regression networks and nbvscore-3; refused for the others)")
    evaluate.add_argument("--hybrid-weight", default="1", help="the hybrid planner: weight of information gain "
                          "against the score network, both standardised (default 1; several separated by commas "
                          "give one planner each)")
    evaluate.add_argument("--hybrid-stride", type=positive_int, default=4, help="the hybrid's information gain casts an image "
                          "this many times coarser than the sensor's from every candidate view (default 4)")
    evaluate.add_argument("--checkpoint", type=Path, help="regression checkpoint (runs/NAME/best.pt; default: the "
                          f"released one, {released['regression']})")
    evaluate.add_argument("--class-checkpoint", type=Path, help="classification checkpoint (--model nbvnet-class; none "
                          "is released: without one the classification planner is skipped)")
    evaluate.add_argument("--planners", help="comma-separated names of registered planners (nbvtrain.planners.PLANNERS: "
                          "scores, regression, classification, infogain, oracle, setcover, random, farthest, viewrank, "
                          "hybrid and the hand-crafted metrics occlusion-aware, unobserved-voxel, rear-side-voxel, "
                          "rear-side-entropy, proximity-count, average-entropy, area-factor, proximity-shadow; default all but hybrid and "
                          "the metrics; docs/evaluation.md) and policies on nbvdata.env's observation as "
                          "module:function or path/to/file.py:function (docs/env.md)")
    evaluate.add_argument("--no-stall", action="store_true", help="regression and classification never repeat a "
                          "scanned view: they fall back to the best alternative not scanned yet (planner names get "
                          "-nostall; off = the paper's behaviour)")
    evaluate.add_argument("--spread", type=non_negative_float, metavar="W", help="regression and classification take "
                          "the unscanned candidate view v with the highest cos(answer, v) - W cos(v, its nearest scan) "
                          "(planner names get -spreadW; off = the paper's behaviour; docs/selection.md measured W)")
    evaluate.add_argument("--scans", type=Integer(2), default=10, help="scans per reconstruction, the start and at "
                          "least one planned one (default 10)")
    evaluate.add_argument("--random-starts", type=non_negative_int, default=0, metavar="K",
                          help="random start views per object besides the front one: K + 1 starts in all (default 0)")
    evaluate.add_argument("--starts", action=_RenamedStarts, help="renamed --random-starts K (refused in one line "
                          "that says so: benchmark's --starts N counts all N starts)")
    evaluate.add_argument("--seed", type=non_negative_int, default=0,
                          help="seed of start views, reference points, random planner")
    evaluate.add_argument("--out", type=Path, default=Path("runs/evaluate"), help="output folder (runs/evaluate)")
    evaluate.add_argument("--config", type=Path, help="YAML of simulation settings, as for nbvdata (default: the "
                          "default scene; configs/smoke.yaml is a small one for a quick try)")
    evaluate.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                          help="override one simulation setting, e.g. --set sensor.noise_std=0.001")
    evaluate.add_argument("--workers", type=non_negative_int, default=1, help="meshes evaluated at once, in "
                          "processes of one thread each; the same outputs but timings (default 1; 0 = one per core)")
    evaluate.add_argument("--floors", action=argparse.BooleanOptionalAction, default=True,
                          help="the set cover of every start (floors.csv; the fewest scans any planner could need), "
                          "up to oracle.cover_node_limit branch-and-bound nodes each (default on; --no-floors for the many "
                          "evaluations that choose a network)")
    evaluate.add_argument("--rerun", type=Path, metavar="DIR", help="also write a Rerun recording per mesh, "
                          "DIR/MESH.rrd, every planner's reconstructions side by side (open one with: rerun "
                          "DIR/MESH.rrd; needs the viz extra; docs/rerun.md)")
    evaluate.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                          help="show a progress bar (default: on a terminal)")
    evaluate.set_defaults(func=cmd_evaluate)


class _RenamedStarts(argparse.Action):
    """``evaluate --starts``: refused in one line, naming --random-starts (it counted the random starts
    besides the front one, where benchmark's --starts counts them all)."""

    def __call__(self, parser, namespace, values, option_string=None):
        parser.error(f"--starts {values}: evaluate's option is --random-starts K, the random start views besides "
                     f"the front one (K + 1 starts in all; --starts {values} was --random-starts {values}); "
                     "benchmark's --starts N counts all N")


def _add_benchmark(sub, released: dict[str, str]) -> None:
    """``benchmark``: its options."""
    bench = sub.add_parser("benchmark", help="the field's protocols (paper, pc-nbv, scvp, objview) on a corpus of "
                           "objects: AUC, coverage, path cost, Chamfer, intervals that decide")
    bench.add_argument("--protocol", default="paper", help="a protocol of configs/protocols (paper, pc-nbv, scvp, "
                       "objview) or a protocol file .yaml (default paper; docs/benchmark.md)")
    bench.add_argument("--meshes", type=Path, help="folder of meshes, one mesh file or a .txt list (default: the bench "
                       "corpus, ../shared/meshes/bench); with --manifest the folder its meshes lie in or below")
    bench.add_argument("--manifest", type=Path, help="a published version (manifests/NAME-X.Y.Z.json): run on exactly "
                       "the meshes of --part of its mesh split (choosing on validation objects: --part val), found under "
                       "--meshes by name and sha256")
    bench.add_argument("--part", help="with --manifest: val (choosing anything), test or train")
    bench.add_argument("--planners", help="comma-separated registered planners and module:function policies "
                       "(default all but hybrid, as evaluate)")
    bench.add_argument("--reference", default="farthest", help="the planner every other is compared with, paired per "
                       "object (default farthest); several, comma-separated: the first for every table, each other "
                       "for the AUC too (e.g. farthest,proximity-count)")
    bench.add_argument("--starts", type=positive_int, default=3, metavar="N", help="start views per object, all "
                       "counted (default 3; evaluate's --random-starts K gives K + 1)")
    bench.add_argument("--seed", type=non_negative_int, default=0, help="seed of start views, reference points, the "
                       "random planner and the bootstrap (default 0)")
    bench.add_argument("--workers", type=non_negative_int, default=1, help="meshes at once, in processes of one thread "
                       "each; the same files but timings (default 1; 0 = one per core)")
    bench.add_argument("--limit", type=positive_int, help="only the first N meshes (a quick try)")
    bench.add_argument("--travel-weight", metavar="L[,L...]", help="also run oracle, scores, infogain and farthest "
                       "weighing the path to each view: score (scaled to [0, 1]) minus L times the path (scaled by the "
                       "longest); and cover and scvp-net dropping each planned view whose detour in the tour (view-"
                       "sphere radii) times L exceeds its probability; one planner NAME-travelL per weight "
                       "(docs/benchmark.md, docs/setcover.md)")
    _cover_model_flags(bench)
    bench.add_argument("--ranker", help="the viewrank planner's model: a ranker file of nbvtrain fit --model "
                          "viewrank-gbm|viewrank-mlp (default: the released one); several, comma-separated, are "
                          "compared as viewrank-FOLDER each")
    bench.add_argument("--score-checkpoint", help="candidate-score checkpoint(s), comma-separated (default: the released "
                       f"one, {released['scores']})")
    bench.add_argument("--checkpoint", type=Path, help="regression checkpoint (default: the released one, "
                       f"{released['regression']})")
    bench.add_argument("--class-checkpoint", type=Path, help="classification checkpoint (none is released)")
    bench.add_argument("--out", type=Path, default=Path("runs/benchmark"), help="output folder (runs/benchmark)")
    bench.add_argument("--config", type=Path, help="YAML of simulation settings under the protocol's")
    bench.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                       help="override one setting after the protocol's, e.g. --set views.reach=hemi")
    bench.add_argument("--rerun", type=Path, metavar="DIR", help="also write a Rerun recording per mesh (docs/rerun.md)")
    bench.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                       help="show a progress bar (default: on a terminal)")
    bench.set_defaults(func=cmd_benchmark)


def _add_release(sub, released: dict[str, str]) -> None:
    """``release``: its options."""
    release = sub.add_parser("release", help="write released models and their model card from fit runs",
                             description="Copy the best epochs of fit runs (or chosen checkpoints of them) as float16 "
                             "checkpoints with a model card and reference answers (what ships in nbvtrain/released/).")
    release.add_argument("--scores", type=Path, help="run folder of a candidate-score network (nbvscore-*: its "
                         "best.pt, the lowest validation loss), or a checkpoint file of such a run (e.g. the snapshot "
                         "the validation objects chose)")
    release.add_argument("--regression", type=Path, help="run folder of a regression network (nbvnet-*), or a "
                         "checkpoint file of such a run")
    release.add_argument("--viewrank", type=Path, help="run folder of a ranker (nbvtrain fit --model viewrank-gbm|"
                         "viewrank-mlp: its viewrank.json or .pt and metrics.json), or its model file")
    release.add_argument("--notes", type=Path, help="markdown file: how the released networks were chosen, a section "
                         "of the card (default: the card's section from the last release, if any)")
    release.add_argument("--evaluation", type=Path, nargs="*", default=[], help="output folders of nbvtrain "
                         "evaluate whose summaries go into the card")
    release.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "released",
                         help="folder to write (default: the package's nbvtrain/released)")
    release.set_defaults(func=cmd_release)


@exit_quietly_when_stdout_closes
def main(argv: list[str] | None = None) -> int:
    try:
        import torch  # noqa: F401  (nbvtrain's one optional dependency: nbvdata runs without it)
    except ImportError as error:
        print(f"nbvtrain: error: nbvtrain needs PyTorch, which is not installed ({error}): {INSTALL_TORCH}",
              file=sys.stderr)
        return 2
    args = build_parser().parse_args(argv)
    return run_command("nbvtrain", args)


if __name__ == "__main__":
    sys.exit(main())
