"""What a set of shards holds: samples per mesh, coverage statistics, how labels spread over
the views. Backs ``nbvdata inspect``; reads everything but the grids.

Imported shards (no ``mesh_id``) count under one entry per dataset, named by their ``source``
without its row range; statistics of datasets they lack (gains, overlaps, coverage) show "-".
Shards whose runs left the oracle's path (``move``: exploration, a policy) add how the runs
moved and which policy they followed; shards with point clouds (``points_count``) the mean
number of points scanned by each step.
"""

from __future__ import annotations

import json
import re
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nbvdata.shards import MOVE_RULES, Shard, ShardError
from nbvdata.text import plural


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
    cloud_points: set[int] = field(default_factory=set)  # the shards' state.points (those with clouds)
    scanned_by_step: dict[int, list[int]] = field(default_factory=dict)  # step: [sum of points_count, states]


def dataset_name(source: str) -> str:
    """An imported shard's ``source`` without its row range: the name its samples count under."""
    return re.sub(r" rows \d+-\d+$", "", source)


def summarise(paths: list[Path]) -> Summary:
    """Read the per-sample labels of every shard in ``paths`` (unreadable ones go to problems)."""
    summary = Summary()
    for path in paths:
        try:
            shard = Shard(path)
        except ShardError as error:
            summary.problems.append(str(error))
            continue
        with shard:
            info = shard.info
            summary.shards += 1
            summary.samples += len(shard)
            summary.configs.add(str(shard.file.attrs["config"]))
            summary.view_count = max(summary.view_count, len(shard.file["view_positions"]))
            min_overlap = info.config.get("oracle", {}).get("min_overlap", 0.0)
            for mesh in info.meshes:
                summary.meshes.setdefault(mesh["id"], MeshSummary(mesh["source"])).shards += 1
            if shard.has("mesh_id"):
                mesh_ids = shard["mesh_id"].astype(str)
            else:
                dataset = dataset_name(info.source)
                summary.meshes.setdefault(dataset, MeshSummary(dataset)).shards += 1
                mesh_ids = np.full(len(shard), dataset)
            if not len(shard):
                continue
            runs, steps, nbv = shard["run"], shard["step"], shard["nbv_index"]
            coverage = shard["coverage"] if shard.has("coverage") else None
            summary.nbv_counts.update(nbv.tolist())
            if "policy" in shard.file.attrs:
                summary.policies.add(str(shard.file.attrs["policy"]))
            if shard.has("move"):
                move, moved = shard["move"], shard["move"] >= 0
                summary.moves.update(move[moved].tolist())
                summary.off_label += int((shard["next_view"][moved] != nbv[moved]).sum())
            if shard.has("points_count"):
                summary.cloud_points.add(int(shard.file["points"].shape[1]))
                for step, count in zip(steps.tolist(), shard["points_count"].tolist()):
                    total = summary.scanned_by_step.setdefault(step, [0, 0])
                    total[0] += count
                    total[1] += 1
            if shard.has("gains"):
                summary.best_gain.append(shard["gains"][np.arange(len(nbv)), nbv])
            if shard.has("overlaps"):
                summary.valid_share.append((shard["overlaps"] >= min_overlap).mean(axis=1))
            runs_of = defaultdict(list)
            for i, (mesh_id, run) in enumerate(zip(mesh_ids, runs)):
                runs_of[(mesh_id, int(run))].append(i)
            for (mesh_id, run), rows in runs_of.items():
                entry = summary.meshes.setdefault(mesh_id, MeshSummary(mesh_id[:12]))
                rows = sorted(rows, key=lambda r: steps[r])
                entry.samples += len(rows)
                entry.last_steps[run] = max(entry.last_steps.get(run, 0), int(steps[rows[-1]]))
                if coverage is not None:
                    entry.first_coverage.append(float(coverage[rows[0], 0]))
                    entry.final_coverage.append(float(coverage[rows[-1], 1]))
    return summary


def format_summary(summary: Summary, top: int = 10) -> str:
    """The summary as the text ``nbvdata inspect`` prints."""
    lines = [f"{plural(summary.shards, 'shard')}, {plural(summary.samples, 'sample')}, "
             f"{plural(len(summary.meshes), 'mesh')}, {plural(summary.view_count, 'candidate view')}"]
    if len(summary.configs) > 1:
        lines.append(f"warning: the shards were made with {len(summary.configs)} different settings")
    lines.append("")
    lines.append(f"{'mesh':44s} {'shards':>6s} {'runs':>5s} {'samples':>7s} {'scans/run':>9s} "
                 f"{'cov@1':>6s} {'final':>6s}  (observable coverage, mean over runs)")
    for entry in sorted(summary.meshes.values(), key=lambda e: e.source):
        mean = lambda values: f"{100 * np.mean(values):5.1f}%" if values else "    - "  # noqa: E731
        steps = f"{np.mean(entry.steps):9.1f}" if entry.steps else f"{'-':>9s}"
        lines.append(f"{entry.source[:44]:44s} {entry.shards:6d} {entry.runs:5d} {entry.samples:7d} {steps} "
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
                  f"most frequent NBVs (view: samples): " + ", ".join(
                      f"{view}: {count}" for view, count in summary.nbv_counts.most_common(top))]
    lines += _moves(summary)
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
