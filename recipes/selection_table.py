"""Validation-object means of ``nbvtrain evaluate`` folders, for issue 27's selection (recipes/selection.sh).

    python recipes/selection_table.py runs/selection/val/*          # one row per folder and planner
    python recipes/selection_table.py --top 3 runs/selection/val/scores-3-e*   # the 3 best rows' checkpoints
    python recipes/selection_table.py --stopped 3 runs/selection/val/scores-3-e*  # exit 0 once the
                                                           # last 3 folders (by epoch) brought no new best
    python recipes/selection_table.py --by-scan runs/selection/val/spread*   # mean coverage after
                                                           # every scan, one column per planner

Per folder and planner: the objects and part it evaluated (config.yaml: the published version and
part of ``--manifest``, or the ``--meshes`` folder), the mean coverage after the last scan over
every (object, start) - of all objects, of the shared meshes and of the procedural objects
(``random_*``, ../shared/meshes/extra) - the median time per decision, and its checkpoints. So a
table says which objects chose what. ``--by`` picks the column that ranks (default ``shared``:
the objects nearest to real use; a folder without shared objects ranks by ``all``).
"""

from __future__ import annotations

import argparse
import csv
import re
import statistics
import sys
from pathlib import Path

import yaml

PROCEDURAL = re.compile(r"random_\d+")


def finals(folder: Path) -> dict[str, dict[tuple[str, str], float]]:
    """planner -> {(mesh, start): coverage after its last scan} of ``folder/coverage.csv``."""
    last: dict[tuple[str, str, str], tuple[int, float]] = {}
    with open(folder / "coverage.csv", newline="") as handle:
        for row in csv.DictReader(handle):
            key, scan = (row["planner"], row["mesh"], row["start"]), int(row["scan"])
            if key not in last or scan > last[key][0]:
                last[key] = (scan, float(row["coverage"]))
    found: dict[str, dict[tuple[str, str], float]] = {}
    for (planner, mesh, start), (_, coverage) in last.items():
        found.setdefault(planner, {})[(mesh, start)] = coverage
    return found


def decision_ms(folder: Path) -> dict[str, float]:
    """planner -> median milliseconds per decision."""
    times: dict[str, list[float]] = {}
    with open(folder / "coverage.csv", newline="") as handle:
        for row in csv.DictReader(handle):
            if int(row["scan"]) > 1:
                times.setdefault(row["planner"], []).append(1e3 * float(row["seconds"]))
    return {planner: statistics.median(values) for planner, values in times.items()}


def rows(folders: list[Path]) -> list[dict]:
    """One dict per folder and planner (see the module docstring)."""
    table = []
    for folder in folders:
        if not (folder / "coverage.csv").is_file():
            continue  # an evaluation still running, or killed: not a result
        settings = yaml.safe_load((folder / "config.yaml").read_text())["evaluate"]
        manifest = settings.get("manifest")
        objects = (f"{manifest['name']} {manifest['version']} {manifest['part']}" if manifest
                   else f"--meshes {settings.get('meshes')}")
        times = decision_ms(folder)
        for planner, values in finals(folder).items():
            shared = [v for (mesh, _), v in values.items() if not PROCEDURAL.fullmatch(mesh)]
            procedural = [v for (mesh, _), v in values.items() if PROCEDURAL.fullmatch(mesh)]
            checkpoint = settings.get("checkpoints", {}).get(planner)
            table.append({
                "folder": folder, "planner": planner, "objects": objects,
                "meshes": len({mesh for mesh, _ in values}), "runs": len(values),
                "all": 100 * statistics.mean(values.values()),
                "shared": 100 * statistics.mean(shared) if shared else None,
                "procedural": 100 * statistics.mean(procedural) if procedural else None,
                "ms": times.get(planner), "checkpoint": checkpoint,
            })
    return table


def scan_means(folders: list[Path]) -> tuple[list[str], dict[tuple[str, str, int], float]]:
    """(column names, {(column, group, scan): mean coverage % after that scan}) over every
    (object, start) of each planner of each finished folder; group: all, shared or procedural;
    a column is ``folder/planner`` when several folders are given."""
    values: dict[tuple[str, str, int], list[float]] = {}
    columns: list[str] = []
    finished = [folder for folder in folders if (folder / "coverage.csv").is_file()]
    for folder in finished:
        with open(folder / "coverage.csv", newline="") as handle:
            for row in csv.DictReader(handle):
                column = row["planner"] if len(finished) == 1 else f"{folder.name}/{row['planner']}"
                if column not in columns:
                    columns.append(column)
                group = "procedural" if PROCEDURAL.fullmatch(row["mesh"]) else "shared"
                for key in ((column, group, int(row["scan"])), (column, "all", int(row["scan"]))):
                    values.setdefault(key, []).append(float(row["coverage"]))
    return columns, {key: 100 * statistics.mean(v) for key, v in values.items()}


def print_by_scan(folders: list[Path]) -> None:
    columns, means = scan_means(folders)
    for group in ("shared", "procedural", "all"):
        scans = sorted({scan for (_, g, scan) in means if g == group})
        if not scans:
            continue
        print(f"\n{group}: mean coverage % after each scan\n")
        print("| scan | " + " | ".join(columns) + " |\n|---|" + "---|" * len(columns))
        for scan in scans:
            cells = [f"{means[(c, group, scan)]:.1f}" if (c, group, scan) in means else "-" for c in columns]
            print(f"| {scan} | " + " | ".join(cells) + " |")


def rank(row: dict, by: str) -> float:
    return row[by] if row[by] is not None else row["all"]


def epoch_of(folder: Path) -> int:
    """The epoch in a folder name ``NET-eNNN`` (recipes/selection.sh names snapshots' evaluations so)."""
    match = re.search(r"-e(\d+)$", folder.name)
    return int(match.group(1)) if match else -1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", type=Path, nargs="+", help="output folders of nbvtrain evaluate")
    parser.add_argument("--by", choices=["all", "shared", "procedural"], default="shared",
                        help="the mean that ranks (default shared; all where a folder has none)")
    parser.add_argument("--top", type=int, metavar="N", help="print the checkpoints of the N best rows only, "
                        "comma-separated (an ensemble's --score-checkpoint)")
    parser.add_argument("--stopped", type=int, metavar="PATIENCE",
                        help="exit 0 when the last PATIENCE folders by epoch brought no new best, else 1")
    parser.add_argument("--by-scan", action="store_true", help="the mean coverage after every scan instead, one "
                        "column per planner, for the shared meshes, the procedural objects and all")
    args = parser.parse_args(argv)
    table = rows(args.folders)
    if not table:
        print("selection_table: no finished evaluation (coverage.csv) in the folders given", file=sys.stderr)
        return 2
    if args.by_scan:
        print_by_scan(args.folders)
        return 0
    if args.top is not None:
        ranked = sorted(table, key=lambda row: -rank(row, args.by))[:args.top]  # stable: the first of equals
        checkpoints = [row["checkpoint"] for row in ranked]
        print(",".join(",".join(c) if isinstance(c, list) else str(c) for c in checkpoints))
        return 0
    if args.stopped is not None:
        ordered = sorted(table, key=lambda row: epoch_of(row["folder"]))
        best = max(range(len(ordered)), key=lambda i: (rank(ordered[i], args.by), -i))  # earliest of equals
        return 0 if len(ordered) - 1 - best >= args.stopped else 1
    print("| folder | planner | objects | meshes | runs | mean % | shared % | procedural % | ms/decision | "
          "checkpoint |\n|---|---|---|---|---|---|---|---|---|---|")
    best = max(table, key=lambda row: rank(row, args.by))
    for row in sorted(table, key=lambda row: (str(row["folder"]), row["planner"])):
        cells = [f"{row[key]:.1f}" if row[key] is not None else "-" for key in ("all", "shared", "procedural")]
        mark = " **best**" if row is best else ""
        checkpoint = row["checkpoint"]
        checkpoint = ", ".join(checkpoint) if isinstance(checkpoint, list) else checkpoint or "-"
        ms = f"{row['ms']:.1f}" if row["ms"] is not None else "-"
        print(f"| {row['folder'].name} | {row['planner']}{mark} | {row['objects']} | {row['meshes']} | {row['runs']} | "
              f"{' | '.join(cells)} | {ms} | {checkpoint} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
