"""The ``nbvtrain`` command line: train NBV networks on shards, predict NBV poses, plan the NBV
from a robot's scans or OctoMap, score the baselines, evaluate planners in closed-loop
reconstructions and run the field's benchmark protocols.

Expected user errors (a bad setting, a missing or broken shard, checkpoint, cloud or map) print one line
naming the fix and exit with status 2; Ctrl-C during ``fit`` saves a checkpoint first and
exits with 130.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nbvdata.commandline import (Integer, Number, Parser, exit_quietly_when_stdout_closes, fraction, non_negative_float,
                                 non_negative_int, positive_float, positive_int, run_command)
from nbvtrain import __version__
from nbvtrain.commands import (COVER_MODELS, INSTALL_TORCH, RANKERS, SURFACE_MODEL, cmd_baselines, cmd_benchmark,
                               cmd_evaluate, cmd_fit, cmd_plan, cmd_predict, cmd_release)


def _model_file_flags(parser: argparse.ArgumentParser) -> None:
    """evaluate's and benchmark's files of the cover planners (``nbvtrain.planners.CoverPlanner``) and of
    the expected-surface planner (``nbvtrain.planners.SurfacePlanner``)."""
    parser.add_argument("--cover-model", type=Path, help="the cover planner's model: a cover.json of nbvtrain fit "
                        "--model cover-gbm (docs/setcover.md)")
    parser.add_argument("--scvp-checkpoint", type=Path, help="the scvp-net planner's network: a covernet.pt of nbvtrain "
                        "fit --model scvp-net (docs/setcover.md)")
    parser.add_argument("--surface-prior", type=Path, help="the expected-surface planner's surface prior: a "
                        "surface.json of nbvtrain fit --model surface-gbm (docs/viewrank.md)")


def _names(text: str) -> tuple[str, ...]:
    """'base,metrics' -> ('base', 'metrics')."""
    names = tuple(part.strip() for part in text.split(",") if part.strip())
    if not names:
        raise argparse.ArgumentTypeError(f"{text!r}: name at least one group or column, comma-separated")
    return names


def _mesh_weights(text: str) -> tuple[tuple[str, float], ...]:
    """'random_*=0.5,ycb*=2' -> (('random_*', 0.5), ('ycb*', 2.0))."""
    pairs = []
    for part in (part.strip() for part in text.split(",") if part.strip()):
        pattern, _, weight = part.rpartition("=")
        try:
            value = float(weight)
        except ValueError:
            value = -1.0
        if not pattern or not (value > 0 and value < float("inf")):
            raise argparse.ArgumentTypeError(f"{part!r}: give PATTERN=W, W a positive number, e.g. 'random_*=0.5'")
        pairs.append((pattern, value))
    if not pairs:
        raise argparse.ArgumentTypeError(f"{text!r}: give PATTERN=W[,PATTERN=W...]")
    return tuple(pairs)


def _rays(text: str) -> tuple[int, int]:
    """'16x12' -> (16, 12)."""
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give WIDTHxHEIGHT rays per view, e.g. 16x12") from None
    if width < 1 or height < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: each of WIDTH and HEIGHT must be >= 1")
    return width, height


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
    from nbvtrain.networks.models import MODELS

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
    fit.add_argument("--mesh-weight", type=_mesh_weights, help="viewrank-gbm: PATTERN=W[,PATTERN=W...]: the training "
                     "states of meshes whose file name matches PATTERN (fnmatch, the first that does) weigh W, others 1, "
                     "e.g. 'random_*=0.5' (the procedural objects half: the real ones weigh twice as much)")
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
    _model_file_flags(evaluate)
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
    _model_file_flags(bench)
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
