"""Checkpoints of ``nbvtrain fit``: plain data only, written atomically, read without running code.

A checkpoint is a dict of plain data: ``model`` (registry name), ``task``, ``epoch``,
``config`` (the TrainConfig as a dict), ``view_radius``, ``scene`` (``nbvtrain.networks.trained_scene``: the
grid and views of its shards, None when unknown), ``state_dict`` and ``optimizer`` (tensors,
numbers, lists), ``history`` (one dict of numbers per epoch) and ``target``; a score network's
also ``view_units`` ((V, 3) float64 tensor: the candidate views it scores, unit directions), a
point network's (``nbvscore-pc``) ``points`` (the size of the clouds it was trained on).

Every checkpoint is read here, with ``torch.load(weights_only=True)``: a file that carries
pickled Python objects is refused, so no code from it runs. Anything that is not a checkpoint
(missing, empty, text, other bytes, a torch file lacking the keys) raises ``CheckpointError``
with one line that names the file and the fix.

**Weights checksum.** torch reads a damaged tensor without a word (its zip records carry no
check it makes), so every torch model file this package writes - checkpoints
(``save_checkpoint``), ``viewrank-mlp`` rankers, ``scvp-net`` covers, RL actors - also holds
``weights_sha256``: the sha256 of its weights (``weights_digest``), checked before the weights
reach a network (``check_weights``). A file written before the checksums existed has none and
loads as before.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import pickletools
import re
import warnings
from pathlib import Path

import numpy as np
import torch

from nbvdata.core.errors import UserError
from nbvtrain.networks.models import MODELS, NBVNet, ScoreNet, build_model

INFERENCE_KEYS = ("model", "epoch", "config", "state_dict")
RESUME_KEYS = INFERENCE_KEYS + ("optimizer", "history")
USE_FIT = "pass a checkpoint written by nbvtrain fit (runs/NAME/best.pt)"
ZIP_MAGIC = b"PK\x03\x04"
LEGACY_MAGIC = pickle.dumps(torch.serialization.MAGIC_NUMBER, protocol=2)
"""How a checkpoint in torch's format before 1.6 (a sequence of pickles) starts."""


class CheckpointError(UserError):
    """A checkpoint that cannot be read or trusted; the one-line message names the fix."""


WEIGHTS_KEY = "weights_sha256"
"""The key of a torch model file's weights checksum (module docstring)."""


def save_checkpoint(path: Path, state: dict) -> None:
    """Write ``state`` (converted to plain data, see ``plain``) with the checksum of its
    ``state_dict`` (``WEIGHTS_KEY``) to ``path`` whole or not at all."""
    state = plain(state)
    state[WEIGHTS_KEY] = weights_digest(state["state_dict"])
    partial = path.with_name(path.name + ".partial")
    torch.save(state, partial)
    os.replace(partial, path)


def weights_digest(*state_dicts: dict) -> str:
    """The sha256 of the tensors of ``state_dicts`` (name -> tensor, in name order): each name,
    dtype, shape and the tensor's bytes - what changes when a stored weight does."""
    digest = hashlib.sha256()
    for state_dict in state_dicts:
        for name in sorted(state_dict):
            tensor = state_dict[name]
            if not isinstance(tensor, torch.Tensor):
                raise TypeError(f"weights_digest: {name} is a {type(tensor).__name__}, not a tensor")
            tensor = tensor.detach().cpu().contiguous()
            digest.update(f"{name}|{tensor.dtype}|{tuple(tensor.shape)}|".encode())
            digest.update(tensor.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


def check_weights(state: dict, path: Path, fix: str, *keys: str) -> None:
    """CheckpointError when the loaded torch file ``state`` records ``WEIGHTS_KEY`` and the weights
    under ``keys`` (each a name -> tensor dict; default ``state_dict``) do not give it: a damaged
    file, refused before any network reads a weight. A file without the checksum passes."""
    recorded = state.get(WEIGHTS_KEY)
    if recorded is None:
        return
    try:
        actual = weights_digest(*(state[key] for key in keys or ("state_dict",)))
    except (KeyError, TypeError, AttributeError, RuntimeError) as error:
        raise CheckpointError(f"{path}: its weights are unreadable ({type(error).__name__}); {fix}") from None
    if actual != recorded:
        raise CheckpointError(f"{path}: damaged (its weights' sha256 is {actual[:12]}..., the file records "
                              f"{str(recorded)[:12]}...): restore it from where it came, or {fix[0].lower() + fix[1:]}")


def plain(value):
    """``value`` with numpy scalars as Python numbers and numpy arrays as tensors, so that
    ``torch.load(weights_only=True)`` reads it back; TypeError for any other object."""
    if isinstance(value, dict):
        return {key: plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(plain(item) for item in value)
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return torch.from_numpy(value.copy())
    if value is None or isinstance(value, (str, int, float, bool, torch.Tensor)):
        return value
    raise TypeError(f"a checkpoint holds plain data only, not {type(value).__name__}")


def load_checkpoint(path: str | Path, fix: str = USE_FIT, keys: tuple[str, ...] = INFERENCE_KEYS) -> dict:
    """The checkpoint at ``path``, on the CPU, with ``keys`` checked; CheckpointError naming
    ``path`` and ``fix`` otherwise. Never unpickles objects (weights_only=True)."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file; {fix}")
    try:
        with warnings.catch_warnings():  # torch warns of a pickle protocol it was not written with: refused anyway
            warnings.filterwarnings("ignore", message="Detected pickle protocol", category=UserWarning)
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # a foreign file can fail in any way: say what the file is
        raise CheckpointError(f"{path}: {_refusal(path, error)}; {fix}") from None
    if not isinstance(state, dict):
        raise CheckpointError(f"{path}: not an nbvtrain checkpoint (it holds a {type(state).__name__}); {fix}")
    missing = [key for key in keys if key not in state]
    if missing:
        raise CheckpointError(f"{path}: not an nbvtrain checkpoint (no {', '.join(missing)}); {fix}")
    if not isinstance(state["model"], str) or state["model"] not in MODELS:
        raise CheckpointError(f"{path}: not an nbvtrain checkpoint (model {str(state['model'])[:40]!r} is not one of "
                              f"{', '.join(MODELS)}); {fix}")
    kinds = {"epoch": int, "config": dict, "state_dict": dict, "optimizer": dict, "history": list}
    wrong = [key for key in keys if key in kinds and not isinstance(state[key], kinds[key])]
    if wrong:
        raise CheckpointError(f"{path}: not an nbvtrain checkpoint (malformed {', '.join(wrong)}); {fix}")
    check_weights(state, path, fix)
    return state


def _refusal(path: Path, error: Exception) -> str:
    """Why ``torch.load(path, weights_only=True)`` failed, in whole words: the file holds a pickled
    object, is no PyTorch checkpoint, or is a damaged one. Never torch's advice to load it unsafely."""
    try:
        with path.open("rb") as handle:
            head = handle.read(64)
    except OSError as failure:
        return f"cannot be read ({failure.strerror or type(failure).__name__})"
    unsafe = re.search(r"Unsupported global: GLOBAL ([\w.]+)", str(error))
    weights_only = "Weights only load failed" in str(error)
    if head.startswith(ZIP_MAGIC):  # what torch.save writes
        if unsafe or weights_only:
            return _pickled_object(unsafe.group(1) if unsafe else None)
        return "not a readable PyTorch checkpoint (a zip archive, damaged, cut short or not written by torch.save)"
    if len(head) > 1 and head[0] == 0x80 and 2 <= head[1] <= 5:  # a pickle: plain, or torch's legacy format
        if unsafe:
            return _pickled_object(unsafe.group(1))
        if head.startswith(LEGACY_MAGIC):
            return "not a readable PyTorch checkpoint (one in torch's legacy format, damaged or cut short)"
        name = _pickled_global(path)
        if name:
            return _pickled_object(None if name == "?" else name)
        return "not a PyTorch checkpoint (a Python pickle, not written by torch.save)"
    kind = "an empty file" if not head else "a text file" if _is_text(head) else "other bytes"
    return f"not a PyTorch checkpoint ({kind})"


def _pickled_object(name: str | None) -> str:
    return (f"holds a pickled Python object ({f'{name}; ' if name else ''}not plain tensors); refused without "
            "running it")


def _pickled_global(path: Path) -> str | None:
    """The first Python object (``module.name``) the pickles in ``path`` name, found by reading
    their opcodes without unpickling anything; "?" for one whose name is not spelled out there,
    None when they name none."""
    object_opcodes = {"REDUCE", "BUILD", "OBJ", "NEWOBJ", "NEWOBJ_EX", "INST"}
    with path.open("rb") as handle:
        while handle.peek(1):  # one pickle after another, to the end of the file
            strings: list[str] = []  # the strings pushed just before: a STACK_GLOBAL's module and name
            try:
                for opcode, argument, _ in pickletools.genops(handle):
                    if opcode.name == "GLOBAL":
                        return str(argument).replace(" ", ".")
                    if opcode.name == "STACK_GLOBAL":
                        return ".".join(strings[-2:]) if len(strings) >= 2 else "?"
                    if opcode.name in object_opcodes:
                        return "?"
                    if isinstance(argument, str):
                        strings.append(argument)
                    elif opcode.name != "MEMOIZE":
                        strings.clear()
            except Exception:  # noqa: BLE001  (bytes that are no pickle: nothing named)
                return None
    return None


def _is_text(head: bytes) -> bool:
    """Whether the first bytes of a file read as UTF-8 text (a multi-byte letter may be cut at the end)."""
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError as error:
        if error.start < len(head) - 3:
            return False
        text = head[:error.start].decode("utf-8")
    return all(char.isprintable() or char in "\t\n\r\f" for char in text)


def model_from(state: dict, path: Path, fix: str = USE_FIT) -> NBVNet | ScoreNet:
    """The network a loaded checkpoint names, with its weights; CheckpointError when they do not fit."""
    config = state["config"]
    views = None
    if MODELS[state["model"]].task == "scores":
        units = state.get("view_units")
        if not isinstance(units, torch.Tensor) or units.ndim != 2 or units.shape[1] != 3:
            raise CheckpointError(f"{path}: not an nbvtrain checkpoint (a score network without its (V, 3) "
                                  f"view_units); {fix}")
        views = units.double().numpy()
    if MODELS[state["model"]].inputs == "points" and (not isinstance(state.get("points"), int) or state["points"] < 1):
        raise CheckpointError(f"{path}: not an nbvtrain checkpoint (a point network without the size of its clouds, "
                              f"points); {fix}")
    try:
        model = build_model(state["model"], config.get("dropout_from", "conv3"), config.get("dropout", 0.5),
                            views=views)
    except (ValueError, TypeError) as error:
        raise CheckpointError(f"{path}: not an nbvtrain checkpoint (bad settings: {error}); {fix}") from None
    restore(model, state["state_dict"], path, fix)
    return model


def restore(target: torch.nn.Module | torch.optim.Optimizer, state_dict: dict, path: Path, fix: str = USE_FIT,
            what: str = "weights") -> None:
    """``target.load_state_dict(state_dict)``; CheckpointError when they do not fit."""
    try:
        target.load_state_dict(state_dict)
    except (RuntimeError, ValueError, KeyError, TypeError, IndexError) as error:
        first = (str(error).strip().splitlines() or [""])[0][:80]
        raise CheckpointError(f"{path}: its {what} do not fit the network it names ({first}); {fix}") from None
