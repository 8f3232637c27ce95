"""What a set of shards holds: samples per mesh, coverage statistics, how labels spread over
the views. Backs ``nbvdata inspect``; reads everything but the grids.

Imported shards (no ``mesh_id``) count under one entry per dataset, named by their ``source``
without its row range; statistics of datasets they lack (gains, overlaps, coverage) show "-".
Shards whose runs left the oracle's path (``move``: exploration, a policy) add how the runs
moved and which policy they followed; shards with point clouds (``points_count``) the mean
number of points scanned by each step. Meshes of one file name (ShapeNet's
``CAT/ID/models/model_normalized.obj``) show the first 12 hex digits of their id beside it, as
their shards' names do.
"""

from __future__ import annotations

import json
import re
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nbvdata.core.text import plural
from nbvdata.schema.shards import MOVE_RULES, Shard, ShardError, ShardInfo, cloud_points


@dataclass
class MeshSummary:
    source: str
    shards: int = 0
    samples: int = 0
    first_coverage: list[float] = field(default_factory=list)
    final_coverage: list[float] = field(default_factory=list)
    last_steps: dict[int, int] = field(default_factory=dict)  # run: its last step seen

    @property
    def steps(self) -> list[int]:
        """Scans per run (a run split over several shards counts once)."""
        return list(self.last_steps.values())

    @property
    def runs(self) -> int:
        return len(self.last_steps)


@dataclass
class Summary:
    """Statistics over shards; ``problems`` lists shards that could not be read."""

    shards: int = 0
    samples: int = 0
    view_count: int = 0
    meshes: dict[str, MeshSummary] = field(default_factory=dict)
    nbv_counts: Counter = field(default_factory=Counter)
    best_gain: list[np.ndarray] = field(default_factory=list)
    valid_share: list[np.ndarray] = field(default_factory=list)
    configs: set[str] = field(default_factory=set)
    problems: list[str] = field(default_factory=list)
    moves: Counter = field(default_factory=Counter)  # rule code (see MOVE_RULES): moves made by it
    off_label: int = 0  # moves to another view or pose than the state's label
    policies: set[str] = field(default_factory=set)  # JSON ``policy`` attributes
    covers: dict[int, list[np.ndarray]] = field(default_factory=lambda: defaultdict(list))  # step: (k, 3) rows
    # of (cover_size, cover_greedy, proved) of the states at that step
    cloud_points: set[int] = field(default_factory=set)  # the shards' state.points (those with clouds)
    scanned_by_step: dict[int, list[int]] = field(default_factory=dict)  # step: [sum of points_count, states]


def dataset_name(source: str) -> str:
    """An imported shard's ``source`` without its row range: the name its samples count under."""
    return re.sub(r" rows \d+-\d+$", "", source)


def summarise(paths: list[Path]) -> Summary:
    """Read the per-sample labels of every shard in ``paths`` (unreadable or damaged ones go to
    problems and count nowhere else)."""
    summary = Summary()
    for path in paths:
        try:
            with Shard(path) as shard:
                labels = _labels(shard)
        except ShardError as error:
            summary.problems.append(str(error))
            continue
        _add(summary, **labels)
    return summary


LABELS = ("view_positions", "run", "step", "nbv_index", "mesh_id", "coverage", "move", "next_view", "gains",
          "overlaps", "cover_size", "cover_greedy", "cover_bound", "points_count")


def _labels(shard: Shard) -> dict:
    """What ``summarise`` counts of one shard, read whole first (None for a dataset it lacks)."""
    attrs = shard.file.attrs
    return {"info": shard.info, "config": str(attrs["config"]), "policy": attrs.get("policy"),
            **{name: shard[name] if shard.has(name) else None for name in LABELS}}


def _add(summary: Summary, info: ShardInfo, config: str, policy: str | None, view_positions: np.ndarray,
         run: np.ndarray, step: np.ndarray, nbv_index: np.ndarray, mesh_id: np.ndarray | None,
         coverage: np.ndarray | None, move: np.ndarray | None, next_view: np.ndarray | None,
         gains: np.ndarray | None, overlaps: np.ndarray | None, cover_size: np.ndarray | None,
         cover_greedy: np.ndarray | None, cover_bound: np.ndarray | None,
         points_count: np.ndarray | None) -> None:
    """Count one shard's labels (``_labels``) into ``summary``."""
    summary.shards += 1
    summary.samples += info.samples
    summary.configs.add(config)
    summary.view_count = max(summary.view_count, len(view_positions))
    min_overlap = info.config.get("oracle", {}).get("min_overlap", 0.0)
    for mesh in info.meshes:
        summary.meshes.setdefault(mesh["id"], MeshSummary(mesh["source"])).shards += 1
    if mesh_id is not None:
        mesh_ids = mesh_id.astype(str)
    else:
        dataset = dataset_name(info.source)
        summary.meshes.setdefault(dataset, MeshSummary(dataset)).shards += 1
        mesh_ids = np.full(info.samples, dataset)
    if not info.samples:
        return
    summary.nbv_counts.update(nbv_index.tolist())
    if policy is not None:
        summary.policies.add(str(policy))
    if move is not None:
        moved = move >= 0
        summary.moves.update(move[moved].tolist())
        summary.off_label += int((next_view[moved] != nbv_index[moved]).sum())
    if gains is not None:
        summary.best_gain.append(gains[np.arange(len(nbv_index)), nbv_index])
    if overlaps is not None:
        summary.valid_share.append((overlaps >= min_overlap).mean(axis=1))
    if cover_size is not None:
        for value in np.unique(step):
            at = step == value
            summary.covers[int(value)].append(np.stack([cover_size[at], cover_greedy[at],
                                                        cover_bound[at] == cover_size[at]], axis=1))
    if points_count is not None:
        summary.cloud_points.add(cloud_points(info.config))
        for value, count in zip(step.tolist(), points_count.tolist()):
            total = summary.scanned_by_step.setdefault(value, [0, 0])
            total[0] += count
            total[1] += 1
    runs_of = defaultdict(list)
    for i, (mesh, number) in enumerate(zip(mesh_ids, run)):
        runs_of[(mesh, int(number))].append(i)
    for (mesh, number), rows in runs_of.items():
        entry = summary.meshes.setdefault(mesh, MeshSummary(mesh[:12]))
        rows = sorted(rows, key=lambda r: step[r])
        entry.samples += len(rows)
        entry.last_steps[number] = max(entry.last_steps.get(number, 0), int(step[rows[-1]]))
        if coverage is not None:
            entry.first_coverage.append(float(coverage[rows[0], 0]))
            entry.final_coverage.append(float(coverage[rows[-1], 1]))


def _fitted(text: str, width: int) -> str:
    """``text`` in ``width`` characters: whole, cut at the end, or for a path '...' and its end (a
    path's end tells meshes apart)."""
    if len(text) <= width:
        return text
    return "..." + text[-(width - 3):] if "/" in text else text[:width]


def format_summary(summary: Summary, top: int = 10) -> str:
    """The summary as the text ``nbvdata inspect`` prints."""
    lines = [f"{plural(summary.shards, 'shard')}, {plural(summary.samples, 'sample')}, "
             f"{plural(len(summary.meshes), 'mesh')}, {plural(summary.view_count, 'candidate view')}"]
    if len(summary.configs) > 1:
        lines.append(f"warning: the shards were made with {len(summary.configs)} different settings")
    lines.append("")
    lines.append(f"{'mesh':44s} {'shards':>6s} {'runs':>5s} {'samples':>7s} {'scans/run':>9s} "
                 f"{'cov@1':>6s} {'final':>6s}  (observable coverage, mean over runs)")
    shared = Counter(entry.source for entry in summary.meshes.values())
    for key, entry in sorted(summary.meshes.items(), key=lambda item: (item[1].source, item[0])):
        mean = lambda values: f"{100 * np.mean(values):5.1f}%" if values else "    - "  # noqa: E731
        steps = f"{np.mean(entry.steps):9.1f}" if entry.steps else f"{'-':>9s}"
        # a path under --meshes (ShapeNet's CAT/ID/models/model_normalized.obj) keeps its end, which tells
        # them apart; one source of several ids (shards of separate jobs): the id too, as the shard names have it
        name = _fitted(entry.source, 44) if shared[entry.source] == 1 else f"{_fitted(entry.source, 29)} ({key[:12]})"
        lines.append(f"{name:44s} {entry.shards:6d} {entry.runs:5d} {entry.samples:7d} {steps} "
                     f"{mean(entry.first_coverage)} {mean(entry.final_coverage)}")
    if summary.samples:
        counts = np.array(list(summary.nbv_counts.values()), dtype=np.float64)
        share = counts / counts.sum()
        entropy = float(-(share * np.log(share)).sum())
        used = len(summary.nbv_counts)
        lines += ["", f"labels: {used} of {plural(summary.view_count, 'view')} {'is' if used == 1 else 'are'} "
                  "ever the NBV; "
                  f"label entropy {entropy:.2f} nats (uniform over the used views: {np.log(len(counts)):.2f})",
                  f"gain of the NBV: median {_median(summary.best_gain, '.2f')} of the observable surface; "
                  f"valid views per state: median {_median(summary.valid_share, '.0f')}",
                  "most frequent NBVs (view: samples): " + ", ".join(
                      f"{view}: {count}" for view, count in summary.nbv_counts.most_common(top))]
    lines += _moves(summary)
    lines += format_covers(summary.covers)
    lines += _clouds(summary)
    for problem in summary.problems:
        lines.append(f"unreadable: {problem}")
    return "\n".join(lines)


def _moves(summary: Summary) -> list[str]:
    """How the runs moved, when they left the oracle's path (nothing otherwise)."""
    moved = sum(summary.moves.values())
    if not moved:
        return []
    shares = ", ".join(f"{rule} {100 * summary.moves[code] / moved:.1f}%" for code, rule in enumerate(MOVE_RULES))
    lines = [f"moves: {plural(moved, 'move')} by rule: {shares}; "
             f"{100 * summary.off_label / moved:.1f}% went elsewhere than the state's label"]
    for text in sorted(summary.policies):
        policy = json.loads(text)
        lines.append(f"policy followed: {policy.get('network') or 'a checkpoint'}, checkpoint sha256 {policy['sha256']}")
    return lines


def format_covers(covers: dict[int, list[np.ndarray]], seconds: dict[int, list[float]] | None = None) -> list[str]:
    """The set-cover labels by step: states, mean optimal size, mean greedy size, share proved
    optimal (and seconds per label when ``seconds`` gives them); nothing without labels."""
    if not covers:
        return []
    lines = ["", "set-cover labels by step (fewest views covering the rest; greedy: most new points first):",
             f"{'step':>4s} {'states':>7s} {'optimal':>8s} {'greedy':>7s} {'proved':>7s}"
             + (f" {'s/label':>8s}" if seconds else "")]
    every = []
    for step in sorted(covers):
        rows = np.concatenate(covers[step])
        every.append(rows)
        extra = f" {np.mean(seconds[step]):8.3f}" if seconds else ""
        lines.append(f"{step:4d} {len(rows):7d} {rows[:, 0].mean():8.2f} {rows[:, 1].mean():7.2f} "
                     f"{100 * rows[:, 2].mean():6.1f}%{extra}")
    rows = np.concatenate(every)
    extra = f" {np.mean([t for s in seconds.values() for t in s]):8.3f}" if seconds else ""
    lines.append(f"{'all':>4s} {len(rows):7d} {rows[:, 0].mean():8.2f} {rows[:, 1].mean():7.2f} "
                 f"{100 * rows[:, 2].mean():6.1f}%{extra}")
    if not seconds:
        lines.append("(seconds per label are measured where the labels are made: nbvdata generate prints them)")
    return lines


def _clouds(summary: Summary) -> list[str]:
    """Points scanned per state by step, when the shards hold point clouds (nothing otherwise)."""
    if not summary.scanned_by_step:
        return []
    sizes = ", ".join(str(size) for size in sorted(summary.cloud_points))
    means = ", ".join(f"{step}: {total / states:,.0f}" for step, (total, states) in sorted(summary.scanned_by_step.items()))
    return [f"point clouds: {sizes} points per state (farthest-point sampled); points scanned, mean by step: {means}"]


def _median(parts: list[np.ndarray], spec: str) -> str:
    """The median of the concatenated parts as a percentage, or "-" when there are none."""
    return f"{100 * np.median(np.concatenate(parts)):{spec}}%" if parts else "-"
