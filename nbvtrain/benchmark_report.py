"""What ``nbvtrain benchmark`` writes, from a ``nbvtrain.benchmark.BenchmarkReport``:

    benchmark.md   per budget: each metric's mean and 95 % interval per planner (over objects),
                   the paired differences against the reference planner with win / tie / loss
                   counts, the ranking by AUC ("not separable" where an interval holds 0), and the
                   split by difficulty; then the time per decision (the only part that depends on
                   the machine)
    per_object.csv each object's metrics per planner and budget, the mean over its starts, its
                   set-cover floor and its difficulty third
    runs.csv       every reconstruction's metrics per budget
    coverage.csv   every reconstruction's coverage and path after each scan
    floors.csv     the set cover of each start (``nbvtrain.evaluate.start_floor``)
    timings.csv    the seconds of every decision (apart: the other files are the same bytes
                   whatever the machine, its load and the number of workers)
    plots/         coverage against scans with the interval of the mean over objects, and
                   coverage against the path travelled, per budget
    config.yaml    the protocol, the simulation settings and the arguments
    failures.tsv, tracebacks.txt   meshes that failed, and where a planner raised

A scan-count metric of a start that never reached its target counts as the budget plus one
(censored: "not reached within the budget"). The difficulty of an object is the oracle's AUC at
the first budget, mean over starts (how fast even the greedy best planner covers it: low for
objects with deep self-occlusion, high for convex ones), split into thirds: hard, medium, easy.
"""

from __future__ import annotations

import csv
import io
from collections import defaultdict
from pathlib import Path

import numpy as np
import yaml

from nbvtrain.benchmark import RUN_METRICS, BenchmarkReport
from nbvtrain.evaluate import write_failures
from nbvtrain.statistics import bootstrap_interval, compare, ranking, tertiles

# (column, title, scale, digits, higher is better) of the metrics benchmark.md tabulates
SHOWN = [("auc", "AUC (%)", 100, 1, True), ("coverage", "coverage (%)", 100, 1, True),
         ("observable_coverage", "observable (%)", 100, 1, True), ("path_m", "path (m)", 1, 2, False),
         ("path_radii", "path (radii)", 1, 1, False), ("chamfer", "Chamfer (x1e-3 r^2)", 1000, 3, False)]
COMPARED = ("auc", "observable_coverage", "path_m", "chamfer")
DIFFICULTY = ("hard", "medium", "easy")


def targets_of(report: BenchmarkReport) -> list[str]:
    return [f"scans_to_{round(100 * target)}" for target in report.protocol.targets]


def thresholds_of(report: BenchmarkReport) -> list[str]:
    return [f"{kind}_{t:g}" for t in report.protocol.thresholds for kind in ("sc", "nsc")]


def per_object(report: BenchmarkReport) -> list[dict]:
    """Each (budget, mesh, planner): every run metric's mean over the starts (scan counts censored
    at the budget plus one), the floor and the difficulty third; in budget, mesh, planner order."""
    censor = {label: views + 1 for label, views in report.protocol.budgets.items()}
    runs = defaultdict(list)
    for run in report.runs:
        runs[(run["budget"], run["mesh"], run["planner"])].append(run)
    floors = defaultdict(list)
    for floor in report.floors:
        floors[floor["mesh"]].append(floor)
    meshes = list(dict.fromkeys(run["mesh"] for run in report.runs))
    names = [*RUN_METRICS, *targets_of(report), *thresholds_of(report)]
    rows = []
    for label in report.protocol.budgets:
        for mesh in meshes:
            for planner in report.planners:
                group = runs.get((label, mesh, planner), [])
                if not group:
                    continue
                row = {"budget": label, "mesh": mesh, "planner": planner, "starts": len(group)}
                for name in names:
                    values = [censor[label] if run[name] is None and name.startswith("scans_to") else run[name]
                              for run in group]
                    row[name] = float(np.mean(values))
                mesh_floors = floors.get(mesh, [])
                row["floor"] = float(np.mean([1 + f["cover_size"] for f in mesh_floors])) if mesh_floors else float("nan")
                row["floor_proved"] = float(np.mean([f["cover_bound"] == f["cover_size"] for f in mesh_floors])) \
                    if mesh_floors else float("nan")
                rows.append(row)
    difficulty = _difficulty(rows, report)
    for row in rows:
        row["difficulty"] = difficulty.get(row["mesh"], "")
    return rows


def _difficulty(rows: list[dict], report: BenchmarkReport) -> dict[str, str]:
    """mesh -> hard / medium / easy: thirds of the oracle's AUC at the first budget (none without
    the oracle)."""
    first = next(iter(report.protocol.budgets))
    oracle = [(row["mesh"], row["auc"]) for row in rows if row["budget"] == first and row["planner"] == "oracle"]
    if not oracle:
        return {}
    thirds = tertiles(np.array([auc for _, auc in oracle]))
    return {mesh: DIFFICULTY[third] for (mesh, _), third in zip(oracle, thirds)}


def _values(rows: list[dict], budget: str, planners: list[str], metric: str) -> tuple[list[str], dict[str, np.ndarray]]:
    """(meshes, planner -> (O,) per-object values of ``metric`` at ``budget``, NaN where missing)."""
    meshes = list(dict.fromkeys(row["mesh"] for row in rows if row["budget"] == budget))
    index = {mesh: i for i, mesh in enumerate(meshes)}
    values = {planner: np.full(len(meshes), np.nan) for planner in planners}
    for row in rows:
        if row["budget"] == budget and row["planner"] in values:
            values[row["planner"]][index[row["mesh"]]] = row[metric]
    return meshes, values


def summary_markdown(report: BenchmarkReport, rows: list[dict], reference: str, seed: int) -> str:
    """benchmark.md (module docstring)."""
    protocol, planners = report.protocol, report.planners
    objects = len({row["mesh"] for row in rows})
    starts = max((row["starts"] for row in rows), default=0)
    lines = [f"# Benchmark: protocol {protocol.name}, {objects} objects, {starts} starts each", "",
             f"Protocol: {protocol.source or protocol.name}; budgets {', '.join(protocol.budgets)} (views scanned, "
             f"the start included: {', '.join(str(v) for v in protocol.budgets.values())}). Every value is the mean over "
             f"objects of each object's mean over its starts; [low, high] the 95 % bootstrap interval of that mean "
             f"(objects resampled, seed {seed}). Reference for the paired differences: `{reference}`.", ""]
    for budget in protocol.budgets:
        lines += [f"## {budget}", ""]
        lines += _means_table(rows, budget, planners, report, seed)
        if reference in planners:
            lines += ["", f"Paired differences against `{reference}` (planner - {reference}, per object; wins / ties / "
                          "losses count objects; \"yes\" where the interval excludes 0):", ""]
            lines += _differences_table(rows, budget, planners, reference, seed)
        lines += ["", "Ranking by AUC (each against the next one down, paired over objects):", ""]
        _, values = _values(rows, budget, planners, "auc")
        for position, (planner, mean, verdict) in enumerate(ranking({p: 100 * v for p, v in values.items()}, seed), 1):
            lines.append(f"{position}. `{planner}` {mean:.1f} %" + (f" - {verdict}" if verdict else ""))
        lines += ["", *_difficulty_table(rows, budget, planners, reference, seed), ""]
    lines += ["", "## Time per decision (this machine; not part of the comparable results)", "",
              "| planner | mean ms | decisions |", "|---|---|---|"]
    seconds = defaultdict(list)
    for row in report.rows:
        if row["scan"] > 1:
            seconds[row["planner"]].append(row["seconds"])
    for planner in planners:
        if seconds[planner]:
            lines.append(f"| {planner} | {1e3 * np.mean(seconds[planner]):.2f} | {len(seconds[planner])} |")
    if report.failures:
        lines += ["", *[f"- mesh {name} failed: {reason}" for name, reason in report.failures]]
    return "\n".join(lines) + "\n"


def _means_table(rows, budget, planners, report, seed) -> list[str]:
    shown = SHOWN + [(name, name.replace("_", " "), 1, 2, False) for name in targets_of(report)] + [
        (name, name.replace("_", "@"), 100, 1, True) for name in thresholds_of(report)]
    header = "| planner | " + " | ".join(title for _, title, _, _, _ in shown) + " |"
    lines = [header, "|---" * (len(shown) + 1) + "|"]
    for planner in planners:
        cells = []
        for offset, (name, _, scale, digits, _) in enumerate(shown):
            _, values = _values(rows, budget, [planner], name)
            value = values[planner][np.isfinite(values[planner])] * scale
            if not len(value):
                cells.append("-")
                continue
            low, high = bootstrap_interval(value, seed + offset)
            cells.append(f"{value.mean():.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]")
        lines.append(f"| {planner} | " + " | ".join(cells) + " |")
    floors = [row["floor"] for row in rows if row["budget"] == budget and row["planner"] == planners[0]]
    if floors and np.isfinite(floors).any():
        lines += ["", f"Set-cover floor (the fewest views that reach all the observable surface from the start, "
                      f"mean): {np.nanmean(floors):.1f} views."]
    return lines


def _differences_table(rows, budget, planners, reference, seed) -> list[str]:
    lines = ["| planner | " + " | ".join(f"{title}: difference [95 %], W/T/L, separable"
                                          for name, title, *_ in SHOWN if name in COMPARED) + " |",
             "|---" * (1 + len(COMPARED)) + "|"]
    cells = defaultdict(list)
    for name, _, scale, digits, higher in SHOWN:
        if name not in COMPARED:
            continue
        _, values = _values(rows, budget, planners, name)
        for comparison in compare({p: v * scale for p, v in values.items()}, reference, seed, higher_is_better=higher):
            if comparison.planner == reference:
                continue
            cells[comparison.planner].append(
                f"{comparison.mean:+.{digits}f} [{comparison.low:+.{digits}f}, {comparison.high:+.{digits}f}], "
                f"{comparison.wins}/{comparison.ties}/{comparison.losses}, {'yes' if comparison.separable else 'no'}")
    for planner in planners:
        if planner != reference:
            lines.append(f"| {planner} | " + " | ".join(cells[planner]) + " |")
    return lines


def _difficulty_table(rows, budget, planners, reference, seed) -> list[str]:
    groups = {label: sorted({row["mesh"] for row in rows if row["difficulty"] == label}) for label in DIFFICULTY}
    if not any(groups.values()):
        return ["(No difficulty split: the oracle was not run.)"]
    lines = ["AUC (%) by difficulty (thirds of the objects by the oracle's AUC at the first budget):", "",
             "| planner | " + " | ".join(f"{label} ({len(groups[label])})" for label in DIFFICULTY) + " |",
             "|---" * 4 + "|"]
    for planner in planners:
        cells = []
        for label in DIFFICULTY:
            values = [row["auc"] for row in rows if row["budget"] == budget and row["planner"] == planner
                      and row["difficulty"] == label]
            cells.append(f"{100 * np.mean(values):.1f}" if values else "-")
        lines.append(f"| {planner} | " + " | ".join(cells) + " |")
    if reference not in planners:
        return lines
    lines += ["", f"AUC difference against `{reference}` by difficulty (points; [95 %] over that third's objects; "
                  "W/T/L):", "", "| planner | " + " | ".join(DIFFICULTY) + " |", "|---" * 4 + "|"]
    cells = defaultdict(list)
    for label in DIFFICULTY:
        third = [row for row in rows if row["difficulty"] == label]
        _, values = _values(third, budget, planners, "auc")
        for comparison in compare({p: 100 * v for p, v in values.items()}, reference, seed):
            cells[comparison.planner].append(
                f"{comparison.mean:+.1f} [{comparison.low:+.1f}, {comparison.high:+.1f}] "
                f"{comparison.wins}/{comparison.ties}/{comparison.losses}" if comparison.objects else "-")
    lines += [f"| {planner} | " + " | ".join(cells[planner]) + " |" for planner in planners if planner != reference]
    return lines


def _csv(path: Path, rows: list[dict], columns: list[str]) -> None:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n", extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow({key: _cell(row.get(key)) for key in columns})
    path.write_text(buffer.getvalue())


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return "nan" if not np.isfinite(value) else f"{value:.6g}"
    return str(value)


def write_benchmark(report: BenchmarkReport, out: Path, reference: str, seed: int, settings: dict) -> list[dict]:
    """Write every file of the module docstring into ``out``; returns the per-object rows."""
    out.mkdir(parents=True, exist_ok=True)
    rows = per_object(report)
    extra = [*targets_of(report), *thresholds_of(report)]
    _csv(out / "per_object.csv", rows, ["budget", "mesh", "planner", "difficulty", "starts",
                                        *[m for m in RUN_METRICS if m != "seconds"], *extra, "floor", "floor_proved"])
    _csv(out / "runs.csv", report.runs, ["budget", "mesh", "planner", "start", "start_view",
                                        *[m for m in RUN_METRICS if m != "seconds"], *extra])
    _csv(out / "coverage.csv", report.rows, ["mesh", "planner", "start", "start_view", "scan", "coverage",
                                             "observable_coverage", "path_m", "x", "y", "z", *thresholds_of(report)])
    _csv(out / "timings.csv", report.rows, ["mesh", "planner", "start", "scan", "seconds"])
    _csv(out / "floors.csv", report.floors, ["mesh", "start", "start_view", "cover_size", "cover_bound", "cover_greedy"])
    (out / "benchmark.md").write_text(summary_markdown(report, rows, reference, seed))
    (out / "config.yaml").write_text(yaml.safe_dump(settings, sort_keys=False))
    write_failures(out, report.failures, report.tracebacks)
    if report.rows:
        plot_benchmark(report, out / "plots", seed)
    return rows


def plot_benchmark(report: BenchmarkReport, folder: Path, seed: int) -> list[Path]:
    """Per budget: coverage (%) against scans, a line per planner with the 95 % interval of the
    mean over objects shaded, and coverage against the mean path travelled (m)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    folder.mkdir(parents=True, exist_ok=True)
    curves = defaultdict(lambda: defaultdict(list))  # planner -> scan -> per-object (coverage, path) means
    per_run = defaultdict(list)
    for row in report.rows:
        per_run[(row["planner"], row["mesh"], row["scan"])].append((row["coverage"], row["path_m"]))
    for (planner, mesh, scan), values in per_run.items():
        curves[planner][scan].append(np.mean(values, axis=0))
    paths = []
    for label, views in report.protocol.budgets.items():
        figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
        for offset, planner in enumerate(report.planners):
            scans = [scan for scan in sorted(curves[planner]) if scan <= views]
            if not scans:
                continue
            coverage = [100 * np.array([value[0] for value in curves[planner][scan]]) for scan in scans]
            means = [values.mean() for values in coverage]
            bands = [bootstrap_interval(values, seed + offset, resamples=2000) for values in coverage]
            (line,) = left.plot(scans, means, marker="o", markersize=3, label=planner)
            left.fill_between(scans, [b[0] for b in bands], [b[1] for b in bands], color=line.get_color(), alpha=0.15)
            travelled = [np.mean([value[1] for value in curves[planner][scan]]) for scan in scans]
            right.plot(travelled, means, marker="o", markersize=3, color=line.get_color(), label=planner)
        left.set(xlabel="views scanned", ylabel="coverage (%)", title=f"{report.protocol.name} {label}: mean over "
                 "objects (shaded: 95 % interval)", xlim=(0.5, views + 0.5))
        left.xaxis.set_major_locator(MaxNLocator(integer=True))
        right.set(xlabel="path travelled (m, mean over objects)", ylabel="coverage (%)",
                  title="coverage against the path travelled")
        for axes in (left, right):
            axes.grid(alpha=0.3)
            axes.legend(fontsize=8, loc="lower right")
        figure.tight_layout()
        path = folder / f"{report.protocol.name}-{_slug(label)}.png"
        figure.savefig(path, dpi=100)
        plt.close(figure)
        paths.append(path)
    return paths


def _slug(label: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in label).strip("-").lower()
