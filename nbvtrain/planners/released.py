"""The models released with the package (``nbvtrain/released/``, package data): which file each task
has (``released_files``, from its ``reference.json``), and the paths the planners and ``plan`` use
when no model is given (``released_checkpoint``, ``released_ranker``); ``NoReleasedModel`` says
what to pass instead. ``nbvtrain.release`` writes them.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

from nbvdata.core.errors import UserError

REFERENCE = "reference.json"
"""The file beside the released models that names each task's file (and holds its reference answer)."""


class NoReleasedModel(UserError):
    """No released model is available for a task; the message says what to pass instead."""


def released_folder() -> Path:
    return Path(str(resources.files("nbvtrain") / "released"))


def released_files(folder: Path | None = None) -> dict[str, str]:
    """Task -> checkpoint file name of the models released in ``folder`` (default the package's),
    as its reference.json records them (a bare file name beside it; anything else is ignored)."""
    try:
        recorded = json.loads(((folder or released_folder()) / REFERENCE).read_text())
    except (OSError, ValueError):
        return {}
    files = {task: entry.get("checkpoint") for task, entry in recorded.items() if isinstance(entry, dict)}
    return {task: name for task, name in files.items() if isinstance(name, str) and name == Path(name).name}


PASS_INSTEAD = {"cover": "--cover-model runs/cover-gbm/cover.json",
                "scvp-net": "--scvp-checkpoint runs/scvp-net/covernet.pt",
                "surface": "--surface-prior runs/surface-gbm/surface.json"}
"""What to pass for a task whose model is no network checkpoint (``released_checkpoint``'s message)."""


def released_checkpoint(task: str = "scores") -> Path:
    """The released checkpoint of ``task`` (scores or regression); ``NoReleasedModel`` otherwise."""
    name = released_files().get(task)
    path = released_folder() / name if name else None
    if path is None or not path.is_file():
        instead = PASS_INSTEAD.get(task, "a checkpoint written by nbvtrain fit (runs/NAME/best.pt)")
        raise NoReleasedModel(f"no {task} model is released with this package: pass {instead}")
    return path


def released_ranker() -> Path:
    """The released ranker of candidate views (``nbvtrain.ranking.viewrank``); ``NoReleasedModel`` otherwise."""
    name = released_files().get("viewrank")
    path = released_folder() / name if name else None
    if path is None or not path.is_file():
        raise NoReleasedModel("no viewrank model is released with this package: pass a ranker written by nbvtrain fit "
                              "--model viewrank-gbm (runs/NAME/viewrank.json) with --ranker")
    return path
