"""``nbvtrain fit``: train an NBV network on shards, with checkpoints, curves and resume.

A run folder holds::

    config.yaml   the resolved TrainConfig
    data.json     the shards (absolute paths), the split and its validation samples; when trained
                  on a published version, its manifest (name, version, sha256, path, root)
    metrics.csv   one row per epoch (see COLUMNS)
    curves.png    the loss and error curves so far
    last.pt       weights, optimiser, history after the last epoch; after a Ctrl-C, the state at the
                  last completed batch (``partial``: the epoch, its batches done, their summed loss
                  and torch's random state)
    best.pt       the epoch with the lowest validation loss

Reproducible: the split, the initial weights, each epoch's batch order, its augmentation and
its dropout masks are all derived from ``seed`` (and the epoch number), so a run resumed from
an epoch's checkpoint continues exactly as the uninterrupted run would have; one stopped by
Ctrl-C inside an epoch continues from its last completed batch with the same random state, the
same bits as the uninterrupted run (timings aside). A second Ctrl-C, which may land inside a
batch, keeps last.pt as it was (the last epoch's, or the last batch saved). A loss that is not
finite stops the run in one line (``TrainingDiverged``) before anything of it is saved.

Longer than 600 lines because a run is one state machine: the epoch loop, its checkpoints, the
resume from an epoch or a batch, Ctrl-C and the curves share the run's state, and cutting them
apart would pass that state through every cut.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import platform
import signal
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import torch
import yaml
from torch import nn

from nbvdata.core.config import ConfigError, from_dict, to_dict, to_yaml
from nbvdata.core.errors import UserError
from nbvdata.core.files import sha256_file
from nbvdata.core.text import plural
from nbvdata.schema.manifest import Published, open_verified_for
from nbvdata.schema.shards import CLOUDS, ShardError
from nbvtrain.networks.checkpoint import (RESUME_KEYS, CheckpointError, load_checkpoint, model_from, restore,
                                          save_checkpoint)
from nbvtrain.networks.config import TrainConfig
from nbvtrain.networks.metrics import evaluate, format_ratio
from nbvtrain.networks.models import (NBVNet, ScoreNet, architecture, build_model, class_positions, parameter_count,
                                      turn_closeness, view_state_closeness)
from nbvtrain.networks.scores import near_best_loss, pick, score_loss
from nbvtrain.networks.training_data import (ShardSet, load_shards, load_view_states, published_split,
                                             rotate_quarter_turns, split_indices, to_grids)

COLUMNS = ("epoch", "train_loss", "val_loss", "val_mse", "val_mae", "val_angle_deg", "val_gain_ratio",
           "val_invalid_share", "seconds", "train_samples_per_s", "machine")
EVAL_BATCH = 500


class Interrupted(Exception):
    """Training stopped by Ctrl-C; ``saved``: ``checkpoint`` holds the state where it stopped (else
    it holds the last state saved whole, if any)."""

    def __init__(self, checkpoint: Path, epoch: int, saved: bool = True):
        where = (f"saved {checkpoint}" if saved else f"{checkpoint} holds the last whole state" if checkpoint.exists()
                 else "nothing saved yet")
        super().__init__(f"interrupted in epoch {epoch + 1}; {where}")
        self.checkpoint, self.epoch = checkpoint, epoch


class _StopRequested(Exception):
    """Raised by the training loop at a batch boundary after a Ctrl-C."""


class TrainingDiverged(UserError):
    """The loss became NaN or infinite: nothing of the step is saved; the message names the fix."""


@dataclass
class EpochProgress:
    """How far an epoch has come: batches done and their summed loss (times batch sizes)."""

    epoch: int
    batches: int = 0
    loss_sum: float = 0.0

    def partial(self) -> dict:
        """What last.pt records to resume exactly here: this, and torch's random state (dropout)."""
        state = {"epoch": self.epoch, "batches": self.batches, "loss_sum": self.loss_sum,
                 "torch_rng": torch.get_rng_state()}
        if torch.cuda.is_available() and torch.cuda.is_initialized():
            state["cuda_rng"] = torch.cuda.get_rng_state_all()
        return state


class _StopOnCtrlC:
    """While active, the first Ctrl-C (SIGINT) only sets ``requested``, and the training loop
    stops at the next batch or epoch boundary; a second Ctrl-C raises KeyboardInterrupt at once.

    A KeyboardInterrupt raised wherever the main thread happens to be can land inside
    ``torch.save``, an import or a ``dataclass`` being built by ``exec``; CPython (3.10-3.13) then
    remembers it as unhandled even after fit caught it, and ``python -m nbvtrain`` died by SIGINT
    instead of exiting 130. Only the main thread can set a handler, and one that is not Python's
    default (SIGINT ignored under ``nohup``, or a caller's own) is left alone.
    """

    def __enter__(self) -> "_StopOnCtrlC":
        self.requested, self._previous = False, None
        if (threading.current_thread() is threading.main_thread()
                and signal.getsignal(signal.SIGINT) is signal.default_int_handler):
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def _handle(self, signum: int, frame) -> None:
        self.requested = True
        signal.signal(signal.SIGINT, self._previous)

    def check(self) -> None:
        if self.requested:
            raise _StopRequested

    def __exit__(self, *exc) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)


@dataclass
class FitResult:
    out: Path
    epochs: int
    history: list[dict]
    parameters: int


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device=cuda but torch sees no GPU: use --device cpu or auto")
    return torch.device(name)


def machine(device: torch.device) -> str:
    """What an epoch ran on, for metrics.csv and the model card: "cpu: <model name> (N threads)" or
    "cuda: <GPU name>"."""
    if device.type == "cuda":
        return f"cuda: {torch.cuda.get_device_name(device)}"
    return f"{device.type}: {cpu_name()} ({plural(torch.get_num_threads(), 'thread')})"


def cpu_name() -> str:
    """The CPU's model name (/proc/cpuinfo), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load_run_config(out: Path) -> TrainConfig:
    """The settings saved in run folder ``out`` (for --resume)."""
    path = Path(out) / "config.yaml"
    if not path.is_file():
        raise ConfigError(f"{out} holds no run to resume (no config.yaml): drop --resume to start one")
    return from_dict(TrainConfig, yaml.safe_load(path.read_text()))


def fit(shards: list[Path], config: TrainConfig, out: Path, resume: bool = False,
        progress: bool = False, log: Callable[[str], None] = print, manifest: Path | None = None,
        root: Path | None = None, add_train: list[Path] = ()) -> FitResult:
    """Train ``config.model`` on ``shards``, writing the run folder ``out``.

    With ``manifest`` (a published NAME-X.Y.Z.json) instead of shards: verify its shards (under
    ``root``, default the one it records), then train on exactly them with its ``config.split``
    split; ``add_train`` (shard files) join its training part with every sample (e.g. a DAgger
    round on its training meshes; a shard of a mesh its mesh split holds out is refused: a leak).
    With ``config.init``, the weights start from that checkpoint's. With ``resume``, continue from
    ``out/last.pt`` (same settings but ``epochs``; ``shards`` may be empty to reuse the run's
    shards, manifest and added shards). Raises ``Interrupted`` on Ctrl-C (after saving the state at
    the last completed batch, for the first one).
    """
    out = Path(out)
    checkpoint = _check_run(out, config, resume)
    if config.threads:
        torch.set_num_threads(config.threads)
    device = resolve_device(config.device)
    points = architecture(config.model).inputs == "points"
    shards, published, added = _sources(list(shards), manifest, root, out, resume, list(add_train), points, log)
    if published is not None:
        log(f"{published.label}: {plural(len(shards), 'shard')} verified against {published.path} "
            f"(sha256 {published.sha256[:12]})")
    resumed = None if checkpoint is None else _restored(config, checkpoint, out, device)  # before the data: its errors first
    init = None if resumed is not None or config.init is None else _init_checkpoint(config)
    if resumed is not None:  # data.json's record of the checkpoint the run started from stays
        started_from = completed_init_record(_saved_data(out).get("init"))
    elif init is not None:
        started_from = init_record(Path(config.init), init)
    else:
        started_from = None
    data = load_shards(shards + added, config.memory_limit_gb, config.mixed_scenes,
                       clouds=config.model if points else None, grids=not points)
    try:
        taken = _view_states(data, config)
        scans = None if taken is None or not architecture(config.model).scans else view_state_closeness(
            taken, data.view_units)
        if resumed is None:
            torch.manual_seed(config.seed)
            model = build_model(config.model, config.dropout_from, config.dropout, views=data.view_units)
            if points:  # the clouds enter on the unit sphere's scale, as the targets
                model.point_scale.fill_(1.0 / data.view_radius)
            if init is not None:
                _start_from(model, init, config.init, data)
            model = model.to(device)
            optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
            history: list[dict] = []
            partial = None
        else:
            model, optimizer, history, views, partial = resumed
            if views is not None and (data.view_units is None or views.shape != data.view_units.shape
                                      or not np.allclose(views, data.view_units, atol=1e-9)):
                raise ConfigError(f"--resume: the run in {out} scores other candidate views than these shards': "
                                  "resume on the shards it was trained on, or start a new --out")
        model = _memory_layout(model, device)
        if config.augment and model.inputs == "points":
            raise ConfigError(f"augment=true with {config.model}: quarter turns apply to grids; use augment=false")
        if config.augment and model.task == "scores" and not model.turns:
            raise ConfigError(f"augment=true with {config.model}: its views are outputs, and quarter turns do not map "
                              "the candidate views onto each other; use nbvscore-3 (views as inputs) or augment=false")
        if published is None:
            train_idx, val_idx, split = split_indices(data, config.split, config.val_fraction, config.seed)
        else:
            train_idx, val_idx, split = published_split(published, config.split)
            if added:
                train_idx = _join_added(data, published, split, train_idx)
        # Every input is checked: only now is anything written (a bad shard leaves no run folder).
        _start(out, config)
        _write_text(out / "data.json", json.dumps({
            "shards": [str(Path(p).resolve()) for p in data.paths], "samples": len(data),
            "train_samples": len(train_idx), "val_samples": len(val_idx), "split": split,
            **({} if published is None else {"manifest": published.identity}),
            **({"added_train": [str(Path(p).resolve()) for p in added]} if added else {}),
            **({} if started_from is None else {"init": started_from}),
            "val_indices": val_idx.tolist()}, indent=1, allow_nan=False))
        log(f"{config.model}: {parameter_count(model):,} parameters on {device}; {len(train_idx)} training and "
            f"{plural(len(val_idx), 'validation sample')} ({split['kind']} split) from "
            f"{plural(len(data.paths), 'shard')}")
        _train(model, optimizer, data, taken, scans, train_idx, val_idx, config, device, out, history, progress,
               log, partial)
        return FitResult(out, len(history), history, parameter_count(model))
    finally:
        data.close()


def _restored(config: TrainConfig, checkpoint: dict, out: Path, device: torch.device
              ) -> tuple[NBVNet | ScoreNet, torch.optim.Optimizer, list[dict], np.ndarray | None, dict | None]:
    """The network (``nbvtrain.networks.checkpoint.model_from``: a score network on the views it records),
    optimiser, history, (a score network's) (V, 3) candidate views and the interrupted epoch's
    progress (``_partial``) of the checkpoint a run resumes from."""
    model = model_from(checkpoint, out / "last.pt", _resume_fix(out)).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    restore(optimizer, checkpoint["optimizer"], out / "last.pt", _resume_fix(out), "optimiser state")
    views = checkpoint["view_units"].double().numpy() if model.task == "scores" else None
    return model, optimizer, checkpoint["history"], views, _partial(checkpoint, out)


def _partial(checkpoint: dict, out: Path) -> dict | None:
    """The checkpoint's record of an epoch stopped by Ctrl-C (``EpochProgress.partial``), checked, or None."""
    partial = checkpoint.get("partial")
    if partial is None:
        return None
    kinds = {"epoch": int, "batches": int, "loss_sum": float, "torch_rng": torch.Tensor}
    if not isinstance(partial, dict) or any(not isinstance(partial.get(key), kind) for key, kind in kinds.items()) \
            or partial["epoch"] != len(checkpoint["history"]) + 1:
        raise CheckpointError(f"{out / 'last.pt'}: malformed record of an interrupted epoch; {_resume_fix(out)}")
    return partial


def _view_states(data: ShardSet, config: TrainConfig) -> np.ndarray | None:
    """(N, V) bool view states for a score network, a network that reads the scans or the near-best
    regression loss (None for the others); ShardError when the shards lack what the network learns from."""
    arch = architecture(config.model)
    task = arch.task
    if not (task == "scores" or arch.scans or (task == "regression" and config.regression_loss == "near-best")):
        return None
    if data.gains is None:
        if arch.scans:
            raise ShardError(f"{config.model} reads where the sensor has been, from each state's view state over one "
                             "common view set, which these shards do not all hold (imported data has none): train it "
                             "on shards written by nbvdata generate, or use nbvnet-4-3")
        learns = config.model if task == "scores" else f"{config.model} with regression_loss=near-best"
        raise ShardError(f"{learns} learns from every candidate view's gain and overlap, and these shards do not all "
                         "hold them for one common view set (imported data has none): train it on shards written by "
                         "nbvdata generate" + ("" if task == "scores" else ", or use regression_loss=label"))
    return load_view_states(data.paths, poses="refuse" if task == "scores" else "nearest")


def init_record(path: Path, init: dict) -> dict:
    """data.json's record of the checkpoint ``init`` (at ``path``, its sha256 added) a run starts from
    (``fit --init``), made while it is at hand: its path, sha256 and epoch, the wall time of its epochs
    (its own history) and, under ``from``, the record of the checkpoint it started from in turn - its
    run's data.json "init", or "unknown" where it started from one and its run is not on this machine.
    The release card reads the whole chain from here, even after the files are gone or replaced."""
    record = {"path": str(path.resolve()), "sha256": init["sha256"], "epoch": init["epoch"],
              "seconds": float(sum(row["seconds"] for row in init["history"][:init["epoch"]]))}
    run = next((folder for folder in path.resolve().parents if (folder / "data.json").is_file()), None)
    ancestor = _saved_data(run).get("init") if run is not None else None
    if ancestor is None and init["config"].get("init"):
        ancestor = "unknown"
    return record if ancestor is None else {**record, "from": ancestor}


def completed_init_record(record: dict | None) -> dict | None:
    """An older nbvtrain's ``init`` record (path, sha256, epoch) made whole by ``init_record`` while
    its checkpoint is still the recorded file; as it is otherwise (no "seconds": its time unknown)."""
    if not record or "seconds" in record:
        return record
    path = Path(record["path"])
    try:
        if sha256_file(path) != record["sha256"]:
            return record
        return init_record(path, load_checkpoint(path) | {"sha256": record["sha256"]})
    except (OSError, CheckpointError, ValueError, KeyError):  # gone, unreadable, or a malformed run folder
        return record


def _saved_data(out: Path) -> dict:
    """The ``data.json`` a run folder holds (empty when none)."""
    path = out / "data.json"
    return json.loads(path.read_text()) if path.is_file() else {}


def _sources(shards: list[Path], manifest: Path | None, root: Path | None, out: Path, resume: bool,
             added: list[Path], points: bool,
             log: Callable[[str], None]) -> tuple[list[Path], Published | None, list[Path]]:
    """The shards to train on, when they are a published version's its verified manifest, and the
    shards added to its training part. A network that reads no clouds (``points`` False) accepts a
    published shard whose clouds alone differ (hit points can differ in their last bits across CPUs).

    A resumed run without shards or manifest reuses its own; a resumed run of a published
    version must find the same manifest bytes (sha256) and shards, and the same added shards."""
    recorded = None
    if resume and (out / "data.json").exists():
        saved = _saved_data(out)
        recorded = saved.get("manifest")
        before = [Path(p) for p in saved.get("added_train", [])]
        if added and [p.resolve() for p in added] != before:
            raise ConfigError(f"--resume: the run in {out} adds {plural(len(before), 'shard')} of its own to its "
                              "training part: resume without --add-train (it reuses them), or start a new --out")
        added = before
        if not shards and manifest is None:
            if recorded is None:
                return [Path(p) for p in saved["shards"]], None, []
            manifest, root = Path(recorded["path"]), root or Path(recorded["root"])
    if manifest is None:
        if added:
            raise ConfigError("--add-train joins the training part of a published version: pass its manifest "
                              "(nbvtrain fit manifests/NAME-X.Y.Z.json --split mesh --add-train DIR), or list "
                              "every folder as shards")
        return shards, None, []
    published, accepted = open_verified_for(manifest, root, frozenset() if points else CLOUDS)
    if accepted:
        differ = sorted({array for problem in accepted for array in problem.arrays})
        log(f"{published.label}: {plural(len(accepted), 'shard')} {'differs' if len(accepted) == 1 else 'differ'} "
            f"from the published ones in {', '.join(differ)} only, which this network does not read: trained on "
            "as they are (nbvdata verify names them)")
    if recorded is not None and published.sha256 != recorded["sha256"]:
        raise ConfigError(f"--resume: {out} trains on {recorded['name']} {recorded['version']} (manifest sha256 "
                          f"{recorded['sha256'][:12]}), but {manifest} has sha256 {published.sha256[:12]}: "
                          "resume with that manifest, or start a new --out")
    return published.shard_paths, published, added


def _join_added(data: ShardSet, published: Published, split: dict, train_idx: np.ndarray) -> np.ndarray:
    """The training indices with every sample after the version's own (those of the added shards)
    appended; ConfigError when the split is not by mesh or an added sample's mesh is one the
    split holds out (validation or test): choosing on those objects would then see them trained on."""
    first = sum(int(entry["samples"]) for entry in published.content["shards"])
    where = f"the training part of {published.label}"
    if split["kind"] != "mesh":
        raise ConfigError(f"--add-train joins {where}'s mesh split, which keeps its validation objects apart: "
                          "add --split mesh")
    if data.mesh_ids is None:
        raise ShardError(f"--add-train: the added shards hold no mesh ids (imported data), so nothing shows they "
                         f"stay out of {published.label}'s validation objects: add shards written by nbvdata generate")
    held = set(split["val_meshes"]) | set(split["test_meshes"])
    leaked = sorted(set(data.mesh_ids[first:].tolist()) & held)
    if leaked:
        raise ConfigError(f"--add-train: the added shards hold {plural(len(leaked), 'mesh')} of {published.label}'s "
                          f"validation or test part (mesh id {leaked[0][:12]}...), a leak into the objects that "
                          f"choose: generate them from {where} only (nbvdata generate --manifest "
                          f"{published.path} --part train --meshes ROOT)")
    return np.concatenate([train_idx, np.arange(first, len(data))])


def _init_checkpoint(config: TrainConfig) -> dict:
    """The checkpoint ``config.init`` names, checked to hold ``config.model``, and its sha256."""
    path = Path(config.init)
    state = load_checkpoint(path, "init= (--init) takes a checkpoint written by nbvtrain fit (runs/NAME/best.pt)")
    if state["model"] not in (config.model, architecture(config.model).widens):
        raise ConfigError(f"--init {path}: a {state['model']} checkpoint, and this run trains {config.model}: pass "
                          f"--model {state['model']}, or a checkpoint of {config.model}")
    return state | {"sha256": sha256_file(path)}


def _start_from(model: NBVNet | ScoreNet, init: dict, path: str, data: ShardSet) -> None:
    """Load ``init``'s weights into ``model``; ConfigError when it was trained in another scene or
    (a score network) on other candidate views than ``data``."""
    recorded = init.get("scene")
    if recorded and data.scene and not recorded.get("mixed") and recorded != data.scene:
        key = next(key for key in recorded if recorded.get(key) != data.scene.get(key))
        raise ConfigError(f"--init {path}: trained in another scene ({key} {recorded.get(key)!r}, these shards "
                          f"{data.scene.get(key)!r}): start from a checkpoint of this scene, or without --init")
    units = init.get("view_units")
    if model.task == "scores" and (not isinstance(units, torch.Tensor) or data.view_units is None
                                   or tuple(units.shape) != data.view_units.shape
                                   or not np.allclose(units.double().numpy(), data.view_units, atol=1e-9)):
        raise ConfigError(f"--init {path}: scores other candidate views than these shards': start from a checkpoint "
                          "trained on this view set, or without --init")
    weights = init["state_dict"]
    if init["model"] != model.name:  # the network it widens: the new inputs' weights start at zero
        weights = widened(weights, model.state_dict())
    restore(model, weights, Path(path), "pass a checkpoint of the same network and --dropout-from")


def widened(weights: dict, target: dict) -> dict:
    """``weights`` with each 2-D weight that ``target`` holds with more input columns padded with
    zero columns on the right (the inputs a widened network adds): the same function until they
    are trained."""
    out = dict(weights)
    for key, value in weights.items():
        wanted = target.get(key)
        if (wanted is not None and value.ndim == 2 and wanted.ndim == 2 and wanted.shape[0] == value.shape[0]
                and wanted.shape[1] > value.shape[1]):
            out[key] = torch.cat([value, value.new_zeros(value.shape[0], wanted.shape[1] - value.shape[1])], dim=1)
    return out


def _check_run(out: Path, config: TrainConfig, resume: bool) -> dict | None:
    """Check the run folder without writing to it; return the checkpoint to resume from, if any."""
    last = out / "last.pt"
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: a file, not a folder: choose another --out")
    if not resume:
        if last.exists():
            raise ConfigError(f"{out} already holds a run: add --resume to continue it, or choose another --out")
        return None
    saved = load_run_config(out)
    if to_dict(saved) | {"epochs": 0} != to_dict(config) | {"epochs": 0}:
        changed = [k for k, v in to_dict(config).items() if k != "epochs" and to_dict(saved)[k] != v]
        raise ConfigError(f"--resume: the run in {out} was made with other settings ({', '.join(changed)}); "
                          "only --epochs may change: drop the others or start a new --out")
    if not last.exists():
        return None  # stopped before its first epoch ended: start over in the same folder
    return load_checkpoint(last, _resume_fix(out), RESUME_KEYS)


def _resume_fix(out: Path) -> str:
    return f"restore it from a copy, or start a new run with another --out than {out}"


def _start(out: Path, config: TrainConfig) -> None:
    """Make the run folder and write its settings."""
    out.mkdir(parents=True, exist_ok=True)
    _write_text(out / "config.yaml", to_yaml(config))


def _train(model: NBVNet | ScoreNet, optimizer: torch.optim.Optimizer, data: ShardSet, taken: np.ndarray | None,
           scans: np.ndarray | None,
           train_idx: np.ndarray, val_idx: np.ndarray, config: TrainConfig, device: torch.device, out: Path,
           history: list[dict], progress: bool, log: Callable[[str], None], partial: dict | None = None) -> None:
    """Train from epoch len(history) + 1 to ``config.epochs``; ``partial``: where a Ctrl-C stopped
    that first epoch (``EpochProgress.partial``), which it then continues."""
    palette = torch.from_numpy(data.palette).to(device)
    classes = torch.from_numpy(class_positions()).float().to(device)
    loss_fn = nn.MSELoss() if model.task == "regression" else nn.CrossEntropyLoss()
    first = len(history) + 1
    if first > config.epochs:
        log(f"{out} already has {plural(len(history), 'epoch')} (epochs={config.epochs}): nothing to do")
    best = min((row["val_loss"] for row in history), default=math.inf)
    done = None
    with _StopOnCtrlC() as stop:
        try:
            for epoch in range(first, config.epochs + 1):
                started = time.perf_counter()
                model.train()
                for group in optimizer.param_groups:
                    group["lr"] = learning_rate(config, epoch)
                torch.manual_seed(_epoch_seed(config.seed, epoch))
                rng = np.random.default_rng([config.seed, epoch])
                order = rng.permutation(train_idx)
                turns = rng.integers(0, 4, len(order)) if config.augment else np.zeros(len(order), dtype=np.int64)
                batches = [(order[i:i + config.batch_size], turns[i:i + config.batch_size])
                           for i in range(0, len(order), config.batch_size)]
                done = EpochProgress(epoch)
                if partial is not None and partial["epoch"] == epoch:  # continue where Ctrl-C stopped it
                    done.batches, done.loss_sum = partial["batches"], partial["loss_sum"]
                    torch.set_rng_state(partial["torch_rng"])
                    if "cuda_rng" in partial and device.type == "cuda":
                        torch.cuda.set_rng_state_all(partial["cuda_rng"])
                    log(f"epoch {epoch}: continuing after batch {done.batches} of {len(batches)}")
                bar = _bar(len(order), f"epoch {epoch}/{config.epochs}", progress)
                if bar is not None:
                    bar.update(sum(len(b[0]) for b in batches[:done.batches]))
                _train_epoch(model, optimizer, data, taken, scans, batches, palette, classes, loss_fn, config,
                             device, bar, stop, done)
                if bar is not None:
                    bar.close()
                train_seconds = time.perf_counter() - started
                row = {"epoch": epoch, "train_loss": done.loss_sum / len(order),
                       **_validate(model, data, taken, scans, val_idx, palette, classes, loss_fn, config, device),
                       "seconds": time.perf_counter() - started, "train_samples_per_s": len(order) / train_seconds,
                       "machine": machine(device)}
                history.append(row)
                save_training_state(out / "last.pt", model, optimizer, config, history, epoch, *_recorded(data))
                if row["val_loss"] < best:
                    best = row["val_loss"]
                    save_training_state(out / "best.pt", model, optimizer, config, history, epoch, *_recorded(data))
                _write_csv(out / "metrics.csv", history)
                _plot(out / "curves.png", history, config.model)
                log(f"epoch {epoch}: train {row['train_loss']:.5f}  val {row['val_loss']:.5f}  "
                    f"mae {row['val_mae']:.4f}  angle {row['val_angle_deg']:.1f} deg  "
                    f"gain ratio {format_ratio(row['val_gain_ratio'])}  {row['seconds']:.1f} s")
                stop.check()
        except _StopRequested:  # at a batch boundary: the state there, to continue exactly
            within = done is not None and done.epoch == len(history) + 1 and done.batches > 0
            save_training_state(out / "last.pt", model, optimizer, config, history, len(history), *_recorded(data),
                  partial=done.partial() if within else None)
            raise Interrupted(out / "last.pt", len(history)) from None
        except KeyboardInterrupt:  # anywhere, perhaps inside a batch: last.pt stays the last state saved whole
            raise Interrupted(out / "last.pt", len(history), saved=False) from None


def _train_epoch(model: NBVNet | ScoreNet, optimizer: torch.optim.Optimizer, data: ShardSet,
                 taken: np.ndarray | None, scans: np.ndarray | None, batches: list[tuple[np.ndarray, np.ndarray]],
                 palette: torch.Tensor,
                 classes: torch.Tensor, loss_fn: nn.Module, config: TrainConfig, device: torch.device, bar,
                 stop: _StopOnCtrlC, done: EpochProgress) -> None:
    """One pass over ``batches`` of (indices, quarter turns) from batch ``done.batches`` on,
    counting each in ``done`` (batches, summed loss times batch sizes). Stops at a batch boundary
    when ``stop`` saw a Ctrl-C; TrainingDiverged at a loss that is not finite, before its step."""
    # closing(): an interrupt stops the prefetch thread here, not at interpreter exit
    with contextlib.closing(_prefetch(lambda b: _batch(data, *b, model.inputs), batches[done.batches:])) as prepared:
        for codes, targets, index, turned in prepared:
            grids = _inputs(codes, palette, model.inputs, device)
            if model.task == "scores":
                loss = _score_loss(model, grids, data, taken, index, config, device, turned)[0]
            elif model.task == "regression":
                output = model(grids, _scan_inputs(scans, index, turned, device))
                loss = _regression_loss(output, targets, data, taken, index, turned, loss_fn, config)
            else:
                output = model(grids)
                loss = loss_fn(output, _labels(torch.from_numpy(targets).to(device), classes))
            value = loss.item()
            if not math.isfinite(value):
                raise TrainingDiverged(f"epoch {done.epoch}, batch {done.batches + 1}: the loss is {value} (nothing of "
                                       "this epoch is saved): check the data (nbvdata verify; values out of range are "
                                       "refused when read) or lower --lr")
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            done.batches += 1
            done.loss_sum += value * len(codes)
            if bar is not None:
                bar.update(len(codes))
                bar.set_postfix(loss=f"{value:.4f}")
            stop.check()


def learning_rate(config: TrainConfig, epoch: int) -> float:
    """The learning rate of ``epoch`` (1-based) under ``config.lr_schedule``."""
    if config.lr_schedule == "cosine":
        return config.lr * (1.0 + math.cos(math.pi * (epoch - 1) / config.epochs)) / 2.0
    return config.lr


def _score_loss(model: ScoreNet, grids: torch.Tensor, data: ShardSet, taken: np.ndarray, index: np.ndarray,
                config: TrainConfig, device: torch.device,
                turns: np.ndarray | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(loss, (B, V) scores, (B, V) taken) of a score network on the samples ``index``, whose
    grids were turned by ``turns`` quarter turns (the view directions turn alike)."""
    gains, valid, scanned = (torch.from_numpy(array[index]).to(device) for array in (data.gains, data.valid, taken))
    turned = None if turns is None or not turns.any() else torch.from_numpy(turns).to(device)
    scores = model(grids, scanned, turned)
    return score_loss(scores, gains, valid, scanned, config.score_loss, config.score_temperature), scores, scanned


def _regression_loss(output: torch.Tensor, targets: np.ndarray, data: ShardSet, taken: np.ndarray | None,
                     index: np.ndarray, turns: np.ndarray, loss_fn: nn.Module, config: TrainConfig) -> torch.Tensor:
    """The loss of a regression network's (B, 3) ``output`` on the samples ``index``, whose grids and
    (B, 3) ``targets`` were turned by ``turns``: ``loss_fn`` (squared error) to the targets, or with
    ``config.regression_loss`` near-best ``nbvtrain.networks.scores.near_best_loss``."""
    device = output.device
    labels = torch.from_numpy(np.ascontiguousarray(targets, dtype=np.float32)).to(device)
    if config.regression_loss == "label":
        return loss_fn(output, labels)
    gains, valid, scanned = (torch.from_numpy(array[index]).to(device) for array in (data.gains, data.valid, taken))
    units = torch.from_numpy(data.view_units).to(device, torch.float32)
    return near_best_loss(output, labels, gains, valid, scanned, units, torch.from_numpy(turns).to(device),
                          config.near_best)


def _scan_inputs(scans: np.ndarray | None, index: np.ndarray, turns: np.ndarray,
                 device: torch.device) -> torch.Tensor | None:
    """(B, K) ``scan_closeness`` rows of the samples ``index`` turned by ``turns`` as their grids
    (``turn_closeness``), or None for a network that reads no scans."""
    if scans is None:
        return None
    return torch.from_numpy(turn_closeness(scans[index], turns)).to(device)


def _epoch_seed(seed: int, epoch: int) -> int:
    return int(np.random.default_rng([seed, epoch, 1]).integers(2 ** 62))


def _batch(data: ShardSet, indices: np.ndarray, turns: np.ndarray,
           inputs: str = "grid") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(B, n, n, n) codes (``inputs`` "points": (B, P, 3) clouds) and (B, 3) float32 targets of
    ``indices``, rotated by ``turns``; ``indices``, ``turns``."""
    if inputs == "points":  # no augmentation for point networks (refused in fit)
        return data.clouds.take(indices), data.targets[indices], indices, turns
    codes, targets = data.grids.take(indices), data.targets[indices]
    if turns.any():
        codes, targets = rotate_quarter_turns(codes, targets, turns)
    return codes, np.ascontiguousarray(targets, dtype=np.float32), indices, turns


def _inputs(batch: np.ndarray, palette: torch.Tensor, inputs: str, device: torch.device) -> torch.Tensor:
    """A batch of ``_batch`` as the network's input: (B, 1, n, n, n) grids (channels-last in memory
    on the CPU, as ``_memory_layout`` lays out the network) or (B, P, 3) clouds."""
    if inputs == "points":
        return torch.from_numpy(batch).to(device, non_blocking=True)
    grids = to_grids(batch, palette)
    return grids.contiguous(memory_format=torch.channels_last_3d) if _channels_last(device) else grids


def _memory_layout(model: NBVNet | ScoreNet, device: torch.device) -> NBVNet | ScoreNet:
    """A grid network on the CPU with its 3D convolutions' weights channels-last, the layout oneDNN's
    kernels run fastest (``benchmarks/train.py``: nbvnet-4-3 1.5x, score networks 1.1x); the same
    arithmetic but the order of sums (``tests/test_train.py``). Point networks and other devices as
    they are."""
    if model.inputs != "grid" or not _channels_last(device):
        return model
    return model.to(memory_format=torch.channels_last_3d)


def _channels_last(device: torch.device) -> bool:
    """Whether grid networks and their batches are laid out channels-last on ``device`` (measured
    faster on the CPU only)."""
    return device.type == "cpu"


def _prefetch(make: Callable, items: list) -> Iterator:
    """``make(item)`` for each item, the next one prepared in a thread while the caller works."""
    if not items:
        return
    with ThreadPoolExecutor(1) as pool:
        pending = pool.submit(make, items[0])
        for item in items[1:]:
            ready = pending.result()
            pending = pool.submit(make, item)
            yield ready
        yield pending.result()


def _labels(targets: torch.Tensor, classes: torch.Tensor) -> torch.Tensor:
    """(B, 3) unit targets -> (B,) index of the nearest of the 14 class views."""
    return torch.argmax(targets @ classes.T, dim=1)


def _validate(model: NBVNet | ScoreNet, data: ShardSet, taken: np.ndarray | None, scans: np.ndarray | None,
              val_idx: np.ndarray,
              palette: torch.Tensor, classes: torch.Tensor, loss_fn: nn.Module, config: TrainConfig,
              device: torch.device) -> dict[str, float]:
    """Validation loss and ``nbvtrain.networks.metrics.evaluate``'s scores; a score network's prediction
    is the position of the view it picks (``nbvtrain.networks.scores.pick``)."""
    model.eval()
    predictions, loss = [], 0.0
    with torch.inference_mode():
        for i in range(0, len(val_idx), EVAL_BATCH):
            index = val_idx[i:i + EVAL_BATCH]
            grids = _inputs(_batch(data, index, np.zeros(len(index), dtype=np.int64), model.inputs)[0], palette,
                            model.inputs, device)
            targets = torch.from_numpy(data.targets[index]).to(device)
            if model.task == "scores":
                batch_loss, scores, scanned = _score_loss(model, grids, data, taken, index, config, device)
                loss += batch_loss.item() * len(index)
                predictions.append(data.view_units[pick(scores, scanned)])
                continue
            no_turns = np.zeros(len(index), dtype=np.int64)
            output = model(grids, _scan_inputs(scans, index, no_turns, device))
            if model.task == "regression":
                loss += _regression_loss(output, data.targets[index], data, taken, index, no_turns, loss_fn,
                                         config).item() * len(index)
                predictions.append(output.float().cpu().numpy())
            else:
                loss += loss_fn(output, _labels(targets, classes)).item() * len(index)
                predictions.append(classes[output.argmax(dim=1)].cpu().numpy())
    gains = data.gains[val_idx] if data.gains is not None else None
    valid = data.valid[val_idx] if data.valid is not None else None
    scores = evaluate(np.concatenate(predictions), data.targets[val_idx], gains, data.view_units, valid)
    return {"val_loss": loss / len(val_idx), **{f"val_{k}": v for k, v in scores.items()}}


def save_training_state(path: Path, model: NBVNet | ScoreNet, optimizer: torch.optim.Optimizer,
                        config: TrainConfig,
          history: list[dict], epoch: int, view_radius: float, scene: dict | None = None,
          view_units: np.ndarray | None = None, points: int | None = None, partial: dict | None = None) -> None:
    """A checkpoint: weights, optimiser, settings, model name, history, the scene it was trained in
    (``nbvtrain.networks.trained_scene``), for a score network its (V, 3) candidate views and for a point network the
    size of its clouds (``points``); ``partial``: how far the next epoch had come (``EpochProgress``);
    plain data, written atomically."""
    state = {"model": model.name, "task": model.task, "epoch": epoch, "config": to_dict(config),
             "view_radius": view_radius, "scene": scene, "state_dict": model.state_dict(),
             "optimizer": optimizer.state_dict(), "history": history,
             "target": "unit NBV position (x, y, z) / view radius"}
    if model.task == "scores":
        state |= {"view_units": view_units, "target": "one score per candidate view (view_units), higher = better"}
    if model.inputs == "points":
        state |= {"points": points, "inputs": "partial point cloud (points, 3), object frame, metres"}
    if partial is not None:
        state["partial"] = partial
    save_checkpoint(path, state)


def _recorded(data: ShardSet) -> tuple[float, dict | None, np.ndarray | None, int | None]:
    """What a checkpoint records of its training data: view radius, scene, candidate views, cloud size."""
    return data.view_radius, data.scene, data.view_units, data.cloud_points


def _write_text(path: Path, text: str) -> None:
    partial = path.with_name(path.name + ".partial")
    partial.write_text(text)
    os.replace(partial, path)


def _write_csv(path: Path, history: list[dict]) -> None:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in history:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    _write_text(path, buffer.getvalue())


def curves_figure(history: list[dict], title: str):
    """The learning curves of ``history`` (rows of history.csv): losses and validation MAE (left,
    log scale), validation angle to the label and gain ratio (right, two y axes); each line in a
    legend, whole epochs on the x axes. The caller closes the figure."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    epochs = [row["epoch"] for row in history]
    dots = {"marker": "o", "markersize": 4} if len(epochs) < 30 else {}  # one epoch is a point, not a line
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.8))
    left.plot(epochs, [row["train_loss"] for row in history], label="train loss", **dots)
    left.plot(epochs, [row["val_loss"] for row in history], label="val loss", **dots)
    left.plot(epochs, [row["val_mae"] for row in history], label="val MAE (position)", linestyle="--", **dots)
    left.set_yscale("log")
    left.set_ylabel("loss, MAE (log scale)")
    left.legend()
    right.plot(epochs, [row["val_angle_deg"] for row in history], color="tab:red", label="val angle (deg)", **dots)
    right.set_ylabel("angle to the ground-truth NBV (deg)", color="tab:red")
    lines = right.get_lines()
    if not all(math.isnan(row["val_gain_ratio"]) for row in history):
        twin = right.twinx()
        twin.plot(epochs, [row["val_gain_ratio"] for row in history], color="tab:green", label="val gain ratio", **dots)
        twin.set_ylabel("gain of nearest view / best gain", color="tab:green")
        twin.set_ylim(0, 1.02)
        lines += twin.get_lines()
    right.legend(lines, [line.get_label() for line in lines], loc="best")
    for axes in (left, right):
        axes.set_xlabel("epoch")
        if len(epochs) == 1:  # one epoch: a unit-wide x range around it, not matplotlib's +-0.05
            axes.set_xlim(epochs[0] - 0.5, epochs[0] + 0.5)
        axes.xaxis.set_major_locator(MaxNLocator(integer=True))  # epochs are whole: no tick at 1.5
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def _plot(path: Path, history: list[dict], title: str) -> None:
    """curves.png of ``curves_figure``, written atomically."""
    fig = curves_figure(history, title)  # first: it selects matplotlib's Agg backend
    import matplotlib.pyplot as plt

    partial = path.with_name(path.name + ".partial.png")
    fig.savefig(partial, dpi=90)
    plt.close(fig)
    os.replace(partial, path)


def _bar(total: int, description: str, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm
    return tqdm(total=total, desc=description, unit="sample", leave=False, file=sys.stderr)
