"""What ``nbvtrain benchmark`` writes, from a ``nbvtrain.evaluation.benchmark.BenchmarkReport``:

    benchmark.md   per budget: each metric's mean and 95 % interval per planner (over objects),
                   the paired differences against the reference planner with win / tie / loss
                   counts, the ranking by AUC ("not separable" where an interval holds 0), and the
                   split by difficulty, each table with its number of objects; on fewer than
                   ``nbvtrain.evaluation.statistics.MIN_OBJECTS`` objects the figures and intervals without a
                   verdict, said at the top; then the time per decision (the only part that
                   depends on the machine)
    per_object.csv each object's metrics per planner and budget, the mean over its starts, its
                   set-cover floor and its difficulty third
    runs.csv       every reconstruction's metrics per budget
    coverage.csv   every reconstruction's coverage and path after each scan
    floors.csv     the set cover of each start (``nbvtrain.evaluation.evaluate.start_floor``)
    timings.csv    the seconds of every decision (apart: the other files are the same bytes
                   whatever the machine, its load and the number of workers)
    plots/         coverage against scans with the interval of the mean over objects, and
                   coverage against the path travelled, per budget
    config.yaml    the protocol, the simulation settings and the arguments
    failures.tsv, tracebacks.txt   meshes that failed, and where a planner raised

A scan-count metric of a start that never reached its target counts as the budget plus one
(censored: "not reached within the budget"), its path to the target as the whole budget's path (a
lower bound); benchmark.md says so under each table and counts
the reconstructions that did not reach it ("k/N n.r."). The difficulty of an object is the oracle's AUC at
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

from nbvdata.core.text import plural
from nbvtrain.evaluation.benchmark import RUN_METRICS, BenchmarkReport
from nbvtrain.evaluation.evaluate import write_failures
from nbvtrain.evaluation.statistics import MIN_OBJECTS, bootstrap_interval, compare, ranking, tertiles

# (column, title, scale, digits, higher is better) of the metrics benchmark.md tabulates
SHOWN = [("auc", "AUC (%)", 100, 1, True), ("coverage", "coverage (%)", 100, 1, True),
         ("observable_coverage", "observable (%)", 100, 1, True), ("path_m", "path (m)", 1, 2, False),
         ("path_radii", "path (radii)", 1, 1, False), ("chamfer", "Chamfer (x1e-3 r^2)", 1000, 3, False)]
COMPARED = ("auc", "observable_coverage", "path_m", "chamfer")
DIFFICULTY = ("hard", "medium", "easy")


def targets_of(report: BenchmarkReport) -> list[str]:
    """The scans-to-X columns, then the path-to-X ones, of the protocol's targets."""
    return ([f"scans_to_{round(100 * target)}" for target in report.protocol.targets]
            + [f"path_to_{round(100 * target)}" for target in report.protocol.targets])


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
                    values = [run[name] if run[name] is not None else
                              censor[label] if name.startswith("scans_to") else run["path_m"] for run in group]
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


def summary_markdown(report: BenchmarkReport, rows: list[dict], reference: str | list[str], seed: int) -> str:
    """benchmark.md (module docstring). ``reference``: the planner every other is compared with, or
    several: the first for every table, each other for the AUC (``_auc_against``)."""
    references = [reference] if isinstance(reference, str) else list(reference)
    reference, others = references[0], references[1:]
    protocol, planners = report.protocol, report.planners
    objects = len({row["mesh"] for row in rows})
    starts = max((row["starts"] for row in rows), default=0)
    lines = [f"# Benchmark: protocol {protocol.name}, {plural(objects, 'object')}, {plural(starts, 'start')} each", ""]
    if objects < MIN_OBJECTS:
        lines += [f"**No verdicts: {plural(objects, 'object')}, fewer than {MIN_OBJECTS}.** A 95 % bootstrap interval "
                  f"over so few objects holds the true mean far less often than 95 % (about 93 % of the time on 20 "
                  f"objects, 90 % on 10, half the time on 2), so the figures and intervals below are given without "
                  f"calling a difference separable or a planner ahead: run on at least {MIN_OBJECTS} objects for a "
                  "verdict (the bench corpus has 201).", ""]
    lines += [f"Protocol: {protocol.source or protocol.name}; budgets {', '.join(protocol.budgets)} (views scanned, "
              f"the start included: {', '.join(str(v) for v in protocol.budgets.values())}). Every value is the mean "
              f"over objects of each object's mean over its starts; [low, high] the 95 % bootstrap interval of that "
              f"mean (objects resampled, seed {seed}). Reference for the paired differences: `{reference}`.", "",
              _units(report), ""]
    for budget in protocol.budgets:
        lines += [f"## {budget}", ""]
        lines += _means_table(rows, budget, planners, report, seed)
        if reference in planners:
            lines += ["", f"Paired differences against `{reference}` (planner - {reference}, per object; wins / ties / "
                          "losses count objects; n the objects compared; \"yes\" where the interval excludes 0, "
                          f"\"no verdict\" on fewer than {MIN_OBJECTS} objects):", ""]
            lines += _differences_table(rows, budget, planners, reference, seed)
            if targets_of(report):
                lines += ["", *_targets_against(rows, budget, planners, reference, report, seed)]
            lines += ["", *_step_table(report, budget, planners, reference, seed)]
        for other in others:
            if other in planners:
                lines += ["", *_auc_against(rows, budget, planners, other, seed)]
        _, values = _values(rows, budget, planners, "auc")
        common = int(np.isfinite(np.array(list(values.values()))).all(axis=0).sum())
        lines += ["", f"Ranking by AUC (each against the next one down, paired over the n = {plural(common, 'object')} "
                      "every planner has):", ""]
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


def _units(report: BenchmarkReport) -> str:
    """What the columns of the means tables measure, in which units."""
    text = ("Columns: AUC (%) the area under the coverage curve (PC-NBV's, 100 % for a curve at full coverage "
            "from the first view); coverage (%) of the surface, observable (%) of what some candidate view can see, "
            "after the budget; path (m) the camera's path round the object's bounding sphere, path (radii) the same "
            "in bounding-sphere radii r; Chamfer (x1e-3 r^2) the Chamfer distance (mean squared nearest-neighbour "
            "distance, reference to scanned points and back) in thousandths of r squared; scans to X the first scan "
            "(the start counts) whose observable coverage reaches X %")
    if report.protocol.thresholds:
        text += ("; sc@t (%) the share of the reference points within t radii of a scanned point, nsc@t that share "
                 "of the points some reachable candidate view reaches")
    return text + "."


def _means_table(rows, budget, planners, report, seed) -> list[str]:
    shown = SHOWN + [(name, name.replace("_", " ") + (" (m)" if name.startswith("path") else ""), 1, 2, False)
                     for name in targets_of(report)] + [
        (name, name.replace("_", "@"), 100, 1, True) for name in thresholds_of(report)]
    meshes = {row["mesh"] for row in rows if row["budget"] == budget}
    header = (f"| planner (n = {plural(len(meshes), 'object')}) | " + " | ".join(title for _, title, *_ in shown)
              + " |")
    lines = [header, "|---" * (len(shown) + 1) + "|"]
    for planner in planners:
        cells = []
        runs = [run for run in report.runs if run["budget"] == budget and run["planner"] == planner
                and run["mesh"] in meshes]
        for offset, (name, _, scale, digits, _) in enumerate(shown):
            _, values = _values(rows, budget, [planner], name)
            value = values[planner][np.isfinite(values[planner])] * scale
            if not len(value):
                cells.append("-")
                continue
            low, high = bootstrap_interval(value, seed + offset)
            missed = sum(run[name] is None for run in runs) if name.startswith(("scans_to", "path_to")) else 0
            cells.append(f"{value.mean():.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"
                         + (f", {missed}/{len(runs)} n.r." if missed else ""))
        lines.append(f"| {planner} | " + " | ".join(cells) + " |")
    if targets_of(report):
        views = report.protocol.budgets[budget]
        lines += ["", f"Scans to X: a start that does not reach X % within the budget counts as the budget plus one "
                      f"({views + 1} for these {views} scans) in the means, and its path to X as the whole budget's "
                      "path (a lower bound); \"k/N n.r.\": k of the planner's N reconstructions (objects x starts) did "
                      "not reach it."]
    floors = [row["floor"] for row in rows if row["budget"] == budget and row["planner"] == planners[0]]
    if floors and np.isfinite(floors).any():
        lines += ["", f"Set-cover floor (the fewest views that reach all the observable surface from the start, "
                      f"mean): {np.nanmean(floors):.1f} views."]
    return lines


def _differences_table(rows, budget, planners, reference, seed) -> list[str]:
    lines = ["| planner | n | " + " | ".join(f"{title}: difference [95 %], W/T/L, separable"
                                              for name, title, *_ in SHOWN if name in COMPARED) + " |",
             "|---" * (2 + len(COMPARED)) + "|"]
    cells, objects = defaultdict(list), {}
    for name, _, scale, digits, higher in SHOWN:
        if name not in COMPARED:
            continue
        _, values = _values(rows, budget, planners, name)
        for comparison in compare({p: v * scale for p, v in values.items()}, reference, seed, higher_is_better=higher):
            if comparison.planner == reference:
                continue
            objects.setdefault(comparison.planner, comparison.objects)  # the first metric's: AUC
            cells[comparison.planner].append(
                f"{comparison.mean:+.{digits}f} [{comparison.low:+.{digits}f}, {comparison.high:+.{digits}f}], "
                f"{comparison.wins}/{comparison.ties}/{comparison.losses}, {comparison.verdict}")
    for planner in planners:
        if planner != reference:
            lines.append(f"| {planner} | {objects.get(planner, 0)} | " + " | ".join(cells[planner]) + " |")
    return lines


def _targets_against(rows, budget, planners, reference, report, seed) -> list[str]:
    """Scans and path to each target against ``reference``, paired per object (censored as the means)."""
    names = targets_of(report)
    lines = [f"Scans and path (m) to each target against `{reference}` (planner - {reference}, per object; [95 %], "
             "W/T/L with fewer a win, separable; censored as in the means):", "",
             "| planner | " + " | ".join(name.replace("_", " ") for name in names) + " |", "|---" * (1 + len(names)) + "|"]
    cells = defaultdict(list)
    for name in names:
        _, values = _values(rows, budget, planners, name)
        for comparison in compare(values, reference, seed, higher_is_better=False):
            if comparison.planner != reference:
                cells[comparison.planner].append(f"{comparison.mean:+.2f} [{comparison.low:+.2f}, {comparison.high:+.2f}], "
                                                 f"{comparison.wins}/{comparison.ties}/{comparison.losses}, "
                                                 f"{comparison.verdict}")
    return lines + [f"| {planner} | " + " | ".join(cells[planner]) + " |" for planner in planners if planner != reference]


def _auc_against(rows, budget, planners, reference, seed) -> list[str]:
    """The AUC of every planner against a second reference (e.g. the best hand-crafted metric)."""
    _, values = _values(rows, budget, planners, "auc")
    lines = [f"AUC (points) against `{reference}` (planner - {reference}, per object; [95 %], W/T/L, separable):", "",
             "| planner | n | AUC difference |", "|---|---|---|"]
    for comparison in compare({p: 100 * v for p, v in values.items()}, reference, seed):
        if comparison.planner == reference:
            continue
        lines.append(f"| {comparison.planner} | {comparison.objects} | {comparison.mean:+.1f} [{comparison.low:+.1f}, "
                     f"{comparison.high:+.1f}], {comparison.wins}/{comparison.ties}/{comparison.losses}, "
                     f"{comparison.verdict} |")
    return lines


def step_scans(views: int) -> list[int]:
    """The scans the per-step table shows for a budget of ``views``: each from the second up to 10,
    then a few up to the budget."""
    scans = list(range(2, min(views, 10) + 1))
    return scans + [scan for scan in (12, 15, 20, 25, 31) if 10 < scan <= views and scan not in scans]


def _step_table(report: BenchmarkReport, budget: str, planners: list[str], reference: str, seed: int) -> list[str]:
    """The edge per scan step: observable coverage (points) minus the reference's after each scan,
    paired per object (its mean over starts), [95 %] over the objects."""
    views = report.protocol.budgets[budget]
    scans = step_scans(views)
    by = defaultdict(list)
    for row in report.rows:
        if row["scan"] in scans:
            by[(row["planner"], row["mesh"], row["scan"])].append(row["observable_coverage"])
    meshes = sorted({row["mesh"] for row in report.rows})
    lines = [f"Observable coverage (points) minus `{reference}`'s after each scan (the edge per step; mean over objects "
             "[95 %]):", "", "| planner | " + " | ".join(f"scan {scan}" for scan in scans) + " |",
             "|---" * (1 + len(scans)) + "|"]
    cells = defaultdict(list)
    for scan in scans:
        values = {planner: np.array([100 * np.mean(by[(planner, mesh, scan)]) if by[(planner, mesh, scan)] else np.nan
                                     for mesh in meshes]) for planner in planners}
        for comparison in compare(values, reference, seed):
            cells[comparison.planner].append(f"{comparison.mean:+.1f} [{comparison.low:+.1f}, {comparison.high:+.1f}]"
                                             if comparison.objects else "-")
    lines += [f"| {planner} | " + " | ".join(cells[planner]) + " |" for planner in planners if planner != reference]
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
                  "W/T/L):", "", "| planner | " + " | ".join(f"{label} ({len(groups[label])})" for label in DIFFICULTY)
              + " |", "|---" * 4 + "|"]
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


def write_benchmark(report: BenchmarkReport, out: Path, reference: str | list[str], seed: int,
                    settings: dict) -> list[dict]:
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
