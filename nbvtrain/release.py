"""The released models: the checkpoints commands use when none is given, and how to make them.

They ship inside the package (``nbvtrain/released/``, package data), so a plain ``pip install``
has them: the ranker of candidate views (``viewrank``: the default of ``nbvtrain predict`` and
``plan``), the candidate-score network (``scores``) and the paper's regression network trained on
the same data with the same budget (``regression``, for comparison); docs/released-models.md says
which model each command uses. ``MODEL_CARD.md`` beside them says how they were
made and what they score; ``reference.json`` names each task's checkpoint file and holds its
answer for ``reference_grid()``, which the tests reproduce from the installed files.

``nbvtrain release --scores RUN --regression RUN --evaluation DIR`` writes them from run folders
of ``nbvtrain fit`` (the best epoch's weights: lowest validation loss) or from checkpoint files of
such runs (an epoch's snapshot, e.g. the one the validation objects chose in closed loop), as
float16 (half the bytes; they load as float32), without the optimiser state, each named by its
network (``nbvscore-fc3.pt``), into the package's folder or ``--out``; the card names the files
relative to itself, and ``--notes FILE`` adds how they were chosen.
"""

from __future__ import annotations

import json
import os
import platform
import re
from collections import Counter
from pathlib import Path

import numpy as np
import yaml

from nbvdata.core.config import ConfigError
from nbvdata.core.files import shown_path
from nbvtrain.planners.released import (PASS_INSTEAD,  # noqa: F401  (the lookups' old path: nbvtrain.release)
                                        REFERENCE, NoReleasedModel, released_checkpoint, released_files,
                                        released_folder, released_ranker)

NETWORKS = ("scores", "regression")
"""The released networks' tasks (their checkpoints: torch files, ``released_checkpoint``)."""
TASKS = NETWORKS + ("viewrank",)
"""Everything ``release`` writes, in the card's order: the networks, then the ranker (``released_ranker``)."""
CARD = "MODEL_CARD.md"
NOTES = "How they were chosen"  # the card's section of ``release(notes=...)``
EVALUATIONS = "Evaluations"  # an earlier card's evaluation sections, kept by a release given no --evaluation
KEEP = ("model", "task", "epoch", "config", "view_radius", "scene", "history", "target", "view_units")


def reference_grid() -> np.ndarray:
    """(32, 32, 32) float32: a fixed state to check released weights by - a box seen from +x
    (occupied face, free space in front of it, the rest unknown), built from integers only."""
    grid = np.full((32, 32, 32), 0.5, dtype=np.float32)
    grid[20:32, 4:28, 0:24] = np.float32(0.1192)   # free space between the +x sensor and the box
    grid[19, 10:22, 0:14] = np.float32(0.971)      # the box's face toward +x
    grid[12:19, 10:22, 13] = np.float32(0.7)       # part of its top, seen at a slant
    return grid


def reference_answer(checkpoint: Path) -> dict:
    """What ``checkpoint`` answers for ``reference_grid()`` with nothing scanned: the direction,
    and for a score network the chosen view, its score and the runner-up's."""
    from nbvtrain.networks.predict import Predictor

    predictor = Predictor(checkpoint)
    (prediction,) = predictor.predict(reference_grid())
    answer = {"direction": [round(float(x), 6) for x in prediction.direction]}
    if predictor.view_units is not None:
        scores = predictor.raw(reference_grid())[0]
        order = np.argsort(-scores, kind="stable")
        answer |= {"view": int(order[0]), "score": round(float(scores[order[0]]), 5),
                   "runner_up": int(order[1]), "runner_up_score": round(float(scores[order[1]]), 5)}
    return answer


def release(runs: dict[str, Path], evaluations: list[Path], out: Path,
            notes: str | None = None) -> tuple[list[Path], list[Path]]:
    """Write the released checkpoints of ``runs`` (task -> run folder of nbvtrain fit, meaning its
    best.pt, or a checkpoint file of such a run), each named by its network, the reference answers
    and the model card (with ``notes``, markdown on how they were chosen, and the summary.md tables
    of ``evaluations``, output folders of nbvtrain evaluate; none given: the earlier card's
    evaluation sections stay) into ``out``. A task released before
    into ``out`` and not now keeps its file and its section of the card; one released before under
    another network's name is replaced: (files written, files removed)."""
    import torch

    from nbvtrain.networks.checkpoint import load_checkpoint, save_checkpoint

    chosen = {}  # every run read and checked before anything is written: a bad one leaves no --out behind
    ranker = _ranker_release(runs["viewrank"]) if "viewrank" in runs else None
    for task, given in runs.items():
        if task == "viewrank":
            continue
        run, checkpoint = run_of(given)
        state = load_checkpoint(checkpoint, f"train one with nbvtrain fit --out {run}")
        if state.get("task") != task:
            raise ConfigError(f"{run}: a {state.get('task')} network, not a {task} one")
        try:
            data = json.loads((run / "data.json").read_text())
        except (OSError, ValueError) as error:
            raise ConfigError(f"{run / 'data.json'}: cannot be read ({type(error).__name__}): pass a run folder of "
                              "nbvtrain fit") from None
        chosen[task] = run, checkpoint, state, data
    out.mkdir(parents=True, exist_ok=True)
    before = released_files(out)
    try:  # a task released into ``out`` before and not now stays released (named in reference.json)
        answers = {task: entry for task, entry in json.loads((out / REFERENCE).read_text()).items()
                   if task in before and task not in runs and (out / before[task]).is_file()}
    except (OSError, ValueError):
        answers = {}
    earlier = _card_sections(out / CARD)
    sections = {task: earlier[task] for task in answers if task in earlier}
    notes = notes if notes is not None else earlier.get(NOTES, "").split("\n", 1)[-1]  # kept with the models kept
    written = []
    for task, (run, checkpoint, state, data) in chosen.items():
        slim = {key: state[key] for key in KEEP if key in state}
        slim["state_dict"] = {key: value.half() if value.is_floating_point() else value
                              for key, value in state["state_dict"].items()}
        slim["released_from"] = shown_path(checkpoint)
        path = out / f"{state['model']}.pt"
        history = _run_history(run, state)
        lineage = _lineage(data, state, history)  # before writing: the run may have started from the file it replaces
        save_checkpoint(path, slim)
        answers[task] = {"checkpoint": path.name, **reference_answer(path)}
        written.append(path)
        sections[task] = _card_section(task, run, checkpoint, state, path, data, history, lineage)
    if ranker is not None:
        source, metrics = ranker
        path = out / ("viewrank.json" if source.suffix == ".json" else "viewrank.pt")
        data = source.read_bytes()
        path.write_bytes(data)
        answers["viewrank"] = {"checkpoint": path.name, **ranker_reference_answer(path)}
        written.append(path)
        sections["viewrank"] = _ranker_section(source, path, metrics)
    answers = {task: answers[task] for task in TASKS if task in answers}  # the card's order, whatever came last
    (out / REFERENCE).write_text(json.dumps(answers, indent=1, allow_nan=False) + "\n")
    card = out / CARD
    card.write_text(_card([sections[task] for task in TASKS if task in sections], answers, evaluations, torch.__version__,
                          packaged=out.resolve() == released_folder().resolve(), notes=notes,
                          kept=None if evaluations else earlier.get(EVALUATIONS)))
    kept = {path.name for path in written}
    superseded = [out / before[task] for task in runs if task in before and before[task] not in kept]
    for path in superseded:
        path.unlink(missing_ok=True)
    return written + [out / REFERENCE, card], superseded


def _ranker_release(given: Path) -> tuple[Path, dict]:
    """(model file, its run's metrics.json) of ``--viewrank``: a run folder of ``nbvtrain fit --model
    viewrank-*`` or its model file; the file is loaded (refused in one line if it is no ranker)."""
    from nbvtrain.ranking.viewrank import load_ranker

    folder = given if given.is_dir() else given.parent
    model = given
    if given.is_dir():
        found = [folder / name for name in ("viewrank.json", "viewrank.pt") if (folder / name).is_file()]
        if not found:
            raise ConfigError(f"{given}: no viewrank.json or viewrank.pt in it: pass a run folder of nbvtrain fit "
                              "--model viewrank-gbm|viewrank-mlp")
        model = found[0]
    load_ranker(model)
    try:
        metrics = json.loads((folder / "metrics.json").read_text())
    except (OSError, ValueError) as error:
        raise ConfigError(f"{folder / 'metrics.json'}: cannot be read ({type(error).__name__}): pass the run folder "
                          "nbvtrain fit wrote the ranker into") from None
    return model, metrics


def ranker_reference_answer(path: Path) -> dict:
    """What the ranker in ``path`` answers for ``reference_grid()`` with nothing scanned, among the
    default scene's candidate views: the chosen view, its score and the runner-up's."""
    from nbvdata.core.config import SimConfig
    from nbvdata.core.views import view_sphere
    from nbvtrain.ranking.viewrank import load_ranker

    config = SimConfig()
    scores = load_ranker(path).view_scores(reference_grid(), np.zeros((0, 3)), view_sphere(config.views), config)
    order = np.argsort(-scores, kind="stable")
    return {"view": int(order[0]), "score": round(float(scores[order[0]]), 5), "runner_up": int(order[1]),
            "runner_up_score": round(float(scores[order[1]]), 5)}


def _ranker_section(source: Path, path: Path, metrics: dict) -> str:
    """The card's section on the released ranker, from its run's metrics.json."""
    training = metrics.get("sources", [])
    data = ", ".join(f"{record['name']} {record['version']}" for record in training if "name" in record)
    split = next((record["split_from"] for record in training if "split_from" in record), "the folders' mesh split")
    layouts = ", ".join(f"{layout} {ratio:.3f}" for layout, ratio in metrics.get("per_layout", {}).items())
    far = metrics.get("baselines", {}).get("farthest (its own choice)", float("nan"))
    lines = [f"## viewrank: {metrics['model']} (`{path.name}` beside this card, {path.stat().st_size / 2 ** 20:.1f} MiB)",
             "",
             f"- A ranker of candidate views from per-view features (`nbvtrain.ranking.viewrank`), any view set; released from "
             f"`{shown_path(source)}`.",
             f"- Data: {data or 'shard folders'}; one mesh split for all ({split}): "
             f"{metrics['train_states']} training states ({metrics['train_rows']} rows), {metrics['val_states']} "
             f"validation states (every unscanned view); labels: {metrics['target']} gains.",
             f"- Time: features {metrics['feature_seconds'] / 60:.1f} min{_cache_words(metrics)}, model "
             f"{metrics['model_seconds'] / 60:.1f} min.",
             f"- Validation gain ratio (the chosen view's gain over the best's): {metrics['val_gain_ratio']:.3f} "
             f"(farthest {far:.3f}); per view set: {layouts}.", ""]
    return "\n".join(lines)


def _cache_words(metrics: dict) -> str:
    """' (k of n shards read from the feature cache)' where the fit read some, else ''."""
    hits, total = metrics.get("feature_cache_hits", [0, 0])
    return f" ({hits} of {total} shards' features read from the feature cache of an earlier fit)" if hits else ""


def run_of(given: Path) -> tuple[Path, Path]:
    """(run folder, checkpoint) of a ``--scores``/``--regression`` argument: a run folder of nbvtrain
    fit (its best.pt), or a checkpoint file in or below one (the nearest folder above it holding the
    run's data.json)."""
    if given.is_dir():
        return given, given / "best.pt"
    for folder in given.parents:
        if (folder / "data.json").is_file():
            return folder, given
    raise ConfigError(f"{given}: neither a run folder of nbvtrain fit nor a checkpoint file inside one (no data.json "
                      "in a folder above it): pass the run folder, or a checkpoint of runs/NAME/")


def _card_sections(card: Path) -> dict[str, str]:
    """An existing card's sections that a release of some tasks keeps: task -> its ``## task: ...``
    section, and ``NOTES`` -> how they were chosen (none when there is no card)."""
    text = card.read_text() if card.is_file() else ""
    sections = {}
    for block in text.split("\n## ")[1:]:
        title = block.split("\n", 1)[0]
        key = title.split(":", 1)[0] if ":" in title else title
        if key in (*TASKS, NOTES):
            sections[key] = "## " + block.strip("\n") + "\n"
        elif title.startswith("Evaluation: "):
            sections.setdefault(EVALUATIONS, "")
            sections[EVALUATIONS] += "## " + block.strip("\n") + "\n\n"
    return sections


def _run_history(run: Path, state: dict) -> list[dict]:
    """Every epoch's history row of ``run`` (its last.pt), or ``state``'s where the run has none."""
    from nbvtrain.networks.checkpoint import load_checkpoint

    last = run / "last.pt"
    return load_checkpoint(last)["history"] if last.is_file() else state["history"]


def _lineage(data: dict, state: dict, history: list[dict]) -> list[str]:
    """The card's line on the checkpoints a run started from (``data``: its data.json), for its
    checkpoint ``state`` (``history``: the whole run's)."""
    epoch = state["history"][-1]["epoch"]
    return _lineage_lines(data, epoch, sum(row["seconds"] for row in history[:epoch]))


def _card_section(task: str, run: Path, checkpoint: Path, state: dict, path: Path, data: dict,
                  history: list[dict], lineage: list[str]) -> str:
    """``data``: the run's data.json; ``history``: every epoch of the run; ``lineage``: ``_lineage``'s lines."""
    manifest = data.get("manifest")
    best = state["history"][-1]  # a checkpoint is saved at its epoch
    chosen = ("best epoch (lowest validation loss)" if checkpoint == run / "best.pt"
              else f"epoch `{checkpoint.relative_to(run)}` of the run")
    seconds = sum(row["seconds"] for row in history)
    config = state["config"]
    keys = ("model", "epochs", "batch_size", "lr", "lr_schedule", "dropout_from", "dropout", "augment",
            *(("score_loss",) if task == "scores" else ()), "split", "seed")
    settings = ", ".join(f"{key} {config[key]}" for key in keys if key in config)
    lines = [f"## {task}: {state['model']} (`{path.name}` beside this card, {path.stat().st_size / 2 ** 20:.1f} MiB)",
             ""]
    if manifest:
        lines.append(f"- Data: {manifest['name']} {manifest['version']} (manifest sha256 {manifest['sha256']}), "
                     f"{data['split']['kind']} split: {data['train_samples']} training and {data['val_samples']} "
                     "validation samples.")
    lines += _added_lines(data)
    machines = sorted({row["machine"] for row in history if row.get("machine")})
    where = f" on {' and '.join(machines)}" if machines else ""
    lines += [f"- Settings: {settings}.",
              f"- Training: {len(history)} epochs in {seconds / 60:.1f} min of wall time{where}; released: the "
              f"{chosen}, epoch {best['epoch']}.",
              *lineage,
              f"- Validation samples at the released epoch: loss {best['val_loss']:.4f}, gain ratio "
              f"{best.get('val_gain_ratio', float('nan')):.3f}, invalid picks "
              f"{100 * best.get('val_invalid_share', float('nan')):.1f} %, angle to the label "
              f"{best['val_angle_deg']:.1f} deg, MSE {best['val_mse']:.4f}.", ""]
    return "\n".join(lines)


def _added_lines(data: dict) -> list[str]:
    """The card's line on shards ``fit --add-train`` added to the training part (DAgger rounds), one
    clause per folder, with the policy that rolled it where its ``policy.yaml`` is still there."""
    folders = Counter(Path(shard).parent for shard in data.get("added_train", []))
    if not folders:
        return []
    clauses = []
    for folder, count in folders.items():
        policy = folder / "policy.yaml"
        rolled = yaml.safe_load(policy.read_text()) if policy.is_file() else None
        by = (f", rolled by {rolled.get('network')} (sha256 {str(rolled.get('sha256'))[:12]})"
              if isinstance(rolled, dict) else "")
        clauses.append(f"{count} shards of `{shown_path(folder)}`{by}")
    return [f"- Added to the training part (`fit --add-train`, every state labelled exactly): {'; '.join(clauses)}."]


def _lineage_lines(data: dict, epochs: int, seconds: float) -> list[str]:
    """The card's line on the checkpoints a run started from (``fit --init``), as its data.json
    recorded them (``nbvtrain.networks.train.init_record``; an older record is completed while its file is
    still here), with the epochs and wall time of the whole chain up to the release (``epochs``,
    ``seconds``: the released run's own); where a link has no recorded time, the chain's is unknown."""
    from nbvtrain.networks.train import completed_init_record

    steps, known, seen = [], True, set()
    init = data.get("init")
    while isinstance(init, dict) and init["sha256"] not in seen:  # (a hand-edited data.json could loop)
        seen.add(init["sha256"])
        steps.append(f"`{shown_path(Path(init['path']))}` (epoch {init['epoch']}, sha256 {init['sha256'][:12]})")
        epochs += init["epoch"]
        init = completed_init_record(init)
        if "seconds" not in init:  # the ancestor is not on this machine (or not as it was)
            known = False
            break
        seconds += init["seconds"]
        known, init = known and init.get("from") != "unknown", init.get("from")
    if not steps:
        return []
    total = (f"{epochs} epochs in {seconds / 60:.1f} min of wall time" if known
             else f"at least {epochs} epochs (a run of the chain is not on this machine: its time is unknown)")
    return [f"- Started from (`fit --init`): {', which started from '.join(steps)}; the chain in all: {total}."]


def _evaluate_arguments(path: Path) -> list[str]:
    """The ``evaluate:`` block of an evaluation's config.yaml (its arguments), as lines, every
    absolute path in it as ``shown_path`` gives it (a card records no local roots)."""
    lines = path.read_text().splitlines() if path.is_file() else []
    block = lines[:1]
    for line in lines[1:]:
        if not line.startswith((" ", "-")):
            break
        block.append(re.sub(r"(?<=[:\-] )/\S+", lambda found: shown_path(found.group(0)), line))
    return block


def _card(sections: list[str], answers: dict, evaluations: list[Path], torch_version: str, packaged: bool,
          notes: str | None = None, kept: str | None = None) -> str:
    """The model card; ``packaged``: written into the package's folder, whose models commands use
    by default (elsewhere, they are used with --checkpoint)."""
    from nbvtrain.networks.train import cpu_name

    use = ("the candidate-score network `nbvtrain evaluate`, `predict` and `plan` use by default" if packaged else
           "the candidate-score network (use a file here with `--checkpoint`, or `--score-checkpoint` for "
           "`nbvtrain evaluate`)")
    lines = ["# Model card: the released next-best-view networks", "",
             f"The models: {use}, the paper's regression network for comparison, and the ranker of candidate views "
             "from per-view features (`viewrank`, where released). Each section names its data, settings and "
             "training time. Network weights are float16 (loaded as float32).", "",
             f"This card written on: {cpu_name()}, {os.cpu_count()} cores (each section names the machine its model was "
             "trained on where it is known); "
             f"torch {torch_version}, Python {platform.python_version()}.", ""]
    lines += sections
    if notes:
        lines += [f"## {NOTES}", "", notes.strip(), ""]
    lines += ["## Reference answers", "",
              "For `nbvtrain.release.reference_grid()` with nothing scanned (tests/test_release.py checks that the "
              "installed package reproduces them):", "", "```json", json.dumps(answers, indent=1, allow_nan=False),
              "```", ""]
    if kept:  # the earlier card's evaluations, as they were
        lines += [kept.strip("\n"), ""]
    for evaluation in evaluations:
        summary = (evaluation / "summary.md").read_text()
        lines += [f"## Evaluation: {summary.splitlines()[0].lstrip('# ')} (`{evaluation.name}`)", "",
                  "```yaml", *_evaluate_arguments(evaluation / "config.yaml"), "```", "",
                  summary.split("\n", 1)[1].strip(), ""]
    return "\n".join(lines) + "\n"
