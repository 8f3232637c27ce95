"""The ``nbvdata`` commands: what each subcommand does with its parsed arguments (``cmd_*``),
and what several of them share. ``nbvdata.cli`` defines the options and dispatches to them.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

from nbvdata.core.config import ConfigError, SimConfig, load_config
from nbvdata.core.errors import UserError
from nbvdata.core.text import plural, some_names
from nbvdata.core.userarrays import GridError, NpyError, check_grids, read_npy
from nbvdata.core.views import parse_view_indices
from nbvdata.schema.shards import ShardError, shard_files
from nbvdata.simulation.mesh import ObjectMesh, load_mesh
from nbvdata.simulation.oracle import pack_bits
from nbvdata.simulation.shapes import builtin_object


class UsageError(UserError):
    """A command's arguments that do not fit together; the one-line message names the fix."""


def _load_object(args: argparse.Namespace, config: SimConfig) -> ObjectMesh:
    return load_mesh(args.mesh, config.mesh) if args.mesh else builtin_object(args.shape, config.mesh)


def _parse_indices(text: str, count: int, flag: str = "--views", example: str = "0,120,340") -> list[int]:
    try:
        return parse_view_indices(text, count, flag, example)
    except ValueError as error:
        raise UsageError(str(error)) from None


def cmd_demo(args: argparse.Namespace) -> int:
    """Scan an object from a few views, integrate, report coverage, and render the state (and,
    with --rerun, record every scan)."""
    from nbvdata.simulation.scene import Scene
    from nbvdata.view.render import render_state

    config = load_config(SimConfig, args.config, args.overrides)
    record = _record_module("--rerun") if args.rerun is not None else None
    obj = _load_object(args, config)
    rng = np.random.default_rng(args.seed)
    scene = Scene.build(obj, config, rng)
    grid = scene.new_grid()
    views = rng.choice(len(scene.views), size=min(args.scans, len(scene.views)), replace=False)
    covered = np.zeros(len(scene.coverage.points), dtype=bool)
    print(f"{obj.source}: {plural(len(obj.mesh.faces), 'face')}, {plural(len(scene.views), 'candidate view')}, "
          f"{int(scene.coverage.observable.sum())}/{len(scene.coverage.points)} reference points observable")
    with record.Recording(args.rerun, f"demo {obj.source}") if record else contextlib.nullcontext() as recording:
        run = recording.run(["demo"], scene) if recording is not None else None
        for step, view in enumerate(views, start=1):
            start = time.perf_counter()
            scan = scene.scanner.scan(scene.views[int(view)], rng, cloud=False)
            scene.integrate(grid, scan)
            elapsed = time.perf_counter() - start
            covered |= scene.coverage.covered_by(scan.hit_points)
            total, observable = scene.coverage.coverage(covered)
            print(f"scan {step}: view {int(view):4d}  {int(scan.hit.sum()):5d} returns  "
                  f"coverage {100 * total:5.1f}%  observable {100 * observable:5.1f}%  "
                  f"scan+integrate {1e3 * elapsed:6.1f} ms  {grid.counts()}")
            if run is not None:
                run.scored_step(step, grid.probabilities(), scene.views[int(view)], pack_bits(covered),
                                scene.views[int(views[step])] if step < len(views) else None)
    if recording is not None:
        print(f"wrote {recording.path}")
    total, observable = scene.coverage.coverage(covered)
    title = (f"{obj.source}: {plural(len(views), 'scan')}, coverage {100 * total:.1f}% of the whole surface, "
             f"{100 * observable:.1f}% of the observable")
    out = render_state(grid.probabilities(), config.scene_grid.extent, args.out, scene.views,
                       scanned=[int(v) for v in views], title=title)
    print(f"wrote {out}")
    return 0


def _record_module(flag: str):
    """``nbvdata.view.rerun``, or a UsageError naming the install command when rerun-sdk is missing."""
    try:
        import nbvdata.view.rerun as record
    except ImportError as error:
        raise UsageError(f"{flag}: {error}") from None
    return record


def cmd_generate(args: argparse.Namespace) -> int:
    """Labelled reconstructions of every mesh, written to shards; resumes an interrupted job."""
    from nbvdata.datasets.generate import FAILURES_FILE, RERUN_FOLDER, generate
    from nbvdata.simulation.policy import DEFAULT_PROVIDER, PolicySource
    from nbvdata.simulation.sources import builtin_sources, mesh_sources, part_sources

    flags = {"episode.runs_per_mesh": args.runs_per_mesh, "episode.seed": args.seed,
             "episode.explore": args.explore, "episode.oracle_mix": args.oracle_mix,
             "generate.workers": args.workers, "generate.backend": args.backend,
             "generate.scheduler": args.scheduler}
    overrides = args.overrides + [f"{key}={value}" for key, value in flags.items() if value is not None]
    config = load_config(SimConfig, args.config, overrides)
    if args.rerun_runs:
        _record_module("--rerun-runs")  # missing: said before the job starts
    if args.policy is None and args.policy_provider is not None:
        raise UsageError(f"--policy-provider {args.policy_provider}: give the file it reads too (--policy FILE)")
    policy = None
    if args.policy is not None:
        policy = PolicySource.from_path(args.policy, args.policy_provider or DEFAULT_PROVIDER)
    if args.manifest is not None:
        if args.part is None:
            raise UsageError("--manifest needs --part train, val or test: the part of its mesh split to generate from")
        sources, failures = part_sources(args.manifest, args.part, args.meshes)[0], []
    elif args.part is not None:
        raise UsageError(f"--part {args.part} needs --manifest manifests/NAME-X.Y.Z.json, the published version "
                         "whose mesh split it names")
    elif args.meshes is None:
        sources, failures = builtin_sources(config.mesh), []
    else:
        sources, failures = mesh_sources(args.meshes)
    units = len(sources) * -(-config.episode.runs_per_mesh // (config.generate.runs_per_shard
                                                               or config.episode.runs_per_mesh))
    print(f"nbvdata generate: {plural(len(sources), 'mesh')} x {plural(config.episode.runs_per_mesh, 'run')} "
          f"({plural(units, 'shard')}) -> {args.out}")
    try:
        report = generate(sources, args.out, config, failures, show_progress=args.progress, policy=policy,
                          rerun_runs=args.rerun_runs or 0)
    except KeyboardInterrupt:
        print("nbvdata generate: interrupted; finished shards are kept, run the same command "
              "again to continue", file=sys.stderr)
        return 130
    rate = report.samples / report.seconds if report.seconds else 0.0
    others = len(report.others_done) + len(report.others_running)
    print(f"wrote {plural(report.samples, 'sample')} in {plural(len(report.done), 'shard')} to {args.out} in "
          f"{report.seconds:.1f} s ({rate:.1f} samples/s)" + _already_there(report.skipped)
          + (f"; {plural(others, 'shard')} {'was' if others == 1 else 'were'} left to another process"
             if others else ""))
    recordings = [args.out / RERUN_FOLDER / Path(result.unit.shard_name).with_suffix(".rrd").name
                  for result in report.done if result.unit.runs[0] < (args.rerun_runs or 0)]
    recordings = [path for path in recordings if path.exists()]
    if recordings:
        print(f"{plural(len(recordings), 'Rerun recording')} in {args.out / RERUN_FOLDER} (open one with: "
              f"rerun {recordings[0]})")
    if config.oracle.cover and any(result.cover_seconds for result in report.done):
        from collections import defaultdict

        from nbvdata.schema.summary import format_covers, summarise

        seconds = defaultdict(list)
        for result in report.done:
            for step, spent in result.cover_seconds:
                seconds[step].append(spent)
        mesh_seconds = sum(result.seconds.get("cover_mesh", 0.0) for result in report.done)
        written = [args.out / result.unit.shard_name for result in report.done]
        print("\n".join(format_covers(summarise(written).covers, seconds)[1:]))
        print(f"(plus {mesh_seconds:.1f} s for the meshes' own covers, no view scanned)")
    if report.others_running:
        print(f"nbvdata generate: another process is still writing {plural(len(report.others_running), 'shard')} "
              f"into {args.out}; run the same command again when it has finished to check that every shard is there")
    if report.failures:
        print(f"nbvdata generate: {plural(len(report.failures), 'mesh')} failed, listed in "
              f"{args.out / FAILURES_FILE}", file=sys.stderr)
        return 1
    return 0


def cmd_import_legacy(args: argparse.Namespace) -> int:
    """Stream the authors' published dataset (.zip or .npy) into shards; resumes an interrupted import."""
    from nbvdata.datasets.authors import import_legacy

    try:
        report = import_legacy(args.volumes, args.poses, args.out, args.rows_per_shard, args.limit,
                               show_progress=args.progress)
    except KeyboardInterrupt:
        print("nbvdata import-legacy: interrupted; finished shards are kept, run the same command "
              "again to continue", file=sys.stderr)
        return 130
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    rate = report.rows / report.seconds if report.seconds else 0.0
    print(f"imported {plural(report.rows, 'row')} into {plural(len(report.written), 'shard')} in {args.out} "
          f"({plural(len(report.run_lengths), 'run')}) in {report.seconds:.1f} s ({rate:.0f} rows/s), "
          f"peak memory {peak:.0f} MiB" + _already_there(report.skipped))
    return 0


def _already_there(skipped: list) -> str:
    """"; 3 shards were already there" after a resumed job's report, or nothing."""
    if not skipped:
        return ""
    return f"; {plural(len(skipped), 'shard')} {'was' if len(skipped) == 1 else 'were'} already there"


def cmd_inspect(args: argparse.Namespace) -> int:
    """Print samples per mesh, coverage statistics and the spread of labels over the views; an
    unreadable or damaged shard is an error, reported before anything is printed."""
    from nbvdata.schema.summary import format_summary, summarise

    paths = shard_files(args.shards)
    summary = summarise(paths)
    if summary.problems:
        others = len(summary.problems) - 1
        raise ShardError(summary.problems[0] + (f" (and {plural(others, 'other unreadable shard')})"
                                                if others else ""))
    if args.by_step:  # reads every grid: a damaged one fails before anything is printed
        from nbvdata.datasets.gridstats import by_step, format_by_step

        steps = by_step(paths)
    print(format_summary(summary, top=args.top))
    if args.by_step:
        print("\nGrids by reconstruction step (means; span: median extent of the occupied voxels):")
        print(format_by_step(steps))
    target = args.shards[0] if len(args.shards) == 1 else "DIR"
    read = "the labels counted above and the grids" if args.by_step else \
        "only the labels counted above, not the grids (--by-step reads those too)"
    print(f"\nchecked: {read}; nbvdata verify {target} reads every shard whole")
    return 0


def cmd_publish(args: argparse.Namespace) -> int:
    """Write the manifest, card, Croissant, index and citation files of a dataset version; an
    identical version is kept as is. Given a manifest: all but the manifest, for that version."""
    from nbvdata.datasets.about import load_about
    from nbvdata.datasets.publish import describe, publish
    from nbvdata.schema.manifest import NOT_RECORDED

    started = time.perf_counter()
    about = load_about(args.about, args.license, args.creator, args.url)
    if args.shards_dir.suffix == ".json":
        given = [flag for flag, value in (("--name", args.name), ("--version", args.version), ("--meshes", args.meshes),
                                          ("--notes", args.notes)) if value]
        if given:
            raise UsageError(f"{given[0]} belongs to a folder of shards; a published version keeps its own")
        written = describe(args.shards_dir, about, args.root)
        print(f"{args.shards_dir}: wrote {', '.join(path.name for path in written)} "
              f"({time.perf_counter() - started:.1f} s); the manifest is unchanged")
        return 0
    if args.root is not None:
        raise UsageError("--root belongs to a published version's manifest; a folder of shards is its own root")
    missing = [flag for flag, value in (("--name", args.name), ("--version", args.version)) if not value]
    if missing:
        raise UsageError(f"{' and '.join(missing)} required: name the version, e.g. --name my-shapes --version 1.0.0")
    result = publish(args.shards_dir, args.name, args.version, args.manifests, args.notes, args.meshes,
                     args.seed, args.val_fraction, args.test_fraction, about=about)
    label = f"{args.name} {args.version}"
    if result.identical:
        print(f"{label}: already published, identical ({result.path}); nothing written")
        return 0
    content, totals = result.content, result.content["totals"]
    print(f"published {label}: {plural(totals['shards'], 'shard')}, {plural(totals['samples'], 'sample')}, "
          f"{plural(totals['meshes'], 'mesh')}, "
          f"{totals['bytes'] / 2 ** 20:.1f} MB, in {time.perf_counter() - started:.1f} s")
    print(f"  manifest {result.path}")
    stem = result.path.with_suffix("")
    print(f"  card     {result.path.with_suffix('.md')} (+ {result.path.with_suffix('.png').name}), Hub front matter")
    print(f"  metadata {stem}.croissant.json (Croissant 1.1 + RAI), {stem.name}.samples.csv.gz (sample index), "
          f"{stem.name}.cff, {stem.name}.zenodo.json")
    for kind in ("random", "mesh"):
        print(f"  {kind} split: {_split_counts(content['splits'][kind])}")
    unrecorded = [mesh["source"] for mesh in content["meshes"] if mesh["license"] == NOT_RECORDED]
    if unrecorded:
        print(f"nbvdata publish: no license recorded for {plural(len(unrecorded), 'mesh')} "
              f"({some_names(unrecorded)}): {_license_fix(args.meshes)}, and publish the next version", file=sys.stderr)
    return 0


def _license_fix(meshes: Path | None) -> str:
    """What ``publish`` asks for when meshes have no license: --meshes, a MESHES.tsv in it, or rows in one."""
    table = "tab-separated, with the columns file and license_or_origin, a row per mesh file"
    if meshes is None:
        return f"pass --meshes DIR, the folder the mesh files came from, with a MESHES.tsv ({table})"
    if not any(Path(meshes).rglob("MESHES.tsv")):
        return f"--meshes {meshes} has no MESHES.tsv in it or below: add one ({table})"
    return f"add their rows to a MESHES.tsv in or below --meshes {meshes} ({table})"


def _split_counts(split: dict) -> str:
    """"train 48 (4 meshes), val 12 (1 mesh), ..." for a manifest's split, or why it has none."""
    if "unavailable" in split:
        return split["unavailable"]
    counts = []
    for part in ("train", "val", "test"):
        if part in split:
            meshes = split[part].get("meshes")
            counts.append(f"{part} {split[part]['samples']}" if meshes is None else
                          f"{part} {split[part]['samples']} ({plural(len(meshes), 'mesh')})")
    return ", ".join(counts)


def cmd_verify(args: argparse.Namespace) -> int:
    """Recompute a published version's hashes and counts; name every missing, changed or extra shard.
    Given shards or a folder of them instead of a manifest: read each whole and name every damaged one."""
    from nbvdata.datasets.croissant import check_croissant, croissant_name
    from nbvdata.schema.manifest import Problem, check_shards, verify

    if args.manifest.name.endswith(".croissant.json"):
        return _verify_croissant(args)
    if args.manifest.is_dir() or args.manifest.suffix.lower() in (".h5", ".hdf5"):
        if args.root is not None or args.content:
            raise ConfigError("--root and --content belong to a manifest; a folder of shards is checked as it is")
        started = time.perf_counter()
        paths = shard_files([args.manifest])
        problems = check_shards(paths)
        return _report(problems, time.perf_counter() - started,
                       failed=f"{plural(len(problems), 'damaged shard')} of {len(paths)}",
                       fix="delete them and run nbvdata generate again (it redoes them), or restore them from a good "
                           "copy",
                       ok=f"ok: {plural(len(paths), 'shard')} read whole, every checksum and value range holds")
    result = verify(args.manifest, args.root, by_content=args.content)
    published, totals = result.published, result.published.content["totals"]
    croissant = args.manifest.with_name(croissant_name(args.manifest))
    described = croissant.is_file()
    result.problems.extend(Problem("changed", croissant.name, line) for line in
                           (check_croissant(croissant, published.content) if described else []))
    print(f"{args.manifest}: {published.label}, {plural(totals['shards'], 'shard')}, "
          f"{plural(totals['samples'], 'sample')}, "
          f"in {os.path.normpath(published.root)}")
    kinds = {problem.kind for problem in result.problems}
    fixes = (["restore the files named from a good copy"] if kinds - {"extra"} else []) + (
        ["move the extra ones away (or publish them as a new version)"] if "extra" in kinds else [])
    same = "with the same content" if args.content else "unchanged"
    agrees = f"; {croissant.name} and its sample index agree" if described else ""
    return _report(result.problems, result.seconds, failed=plural(len(result.problems), "problem"),
                   fix=f"this is not the published {published.label}; {' and '.join(fixes)}",
                   ok=f"ok: every shard is there, {same}, with the samples listed; no others{agrees}")


def _verify_croissant(args: argparse.Namespace) -> int:
    """``nbvdata verify NAME.croissant.json``: every local file it lists, hashed against it."""
    from nbvdata.datasets.croissant import check_files

    if args.root is not None or args.content:
        raise ConfigError("--root and --content belong to a manifest; a Croissant's files are where its contentUrls "
                          "say, relative to it")
    started = time.perf_counter()
    problems = check_files(args.manifest)
    return _report(problems, time.perf_counter() - started, failed=plural(len(problems), "problem"),
                   fix=f"these are not the files {args.manifest.name} describes; restore them from a good copy",
                   ok=f"ok: every file {args.manifest.name} lists is there with its sha256")


def _report(problems: list, seconds: float, *, failed: str, fix: str, ok: str) -> int:
    """What ``nbvdata verify`` prints of a check: each problem, then ``failed`` with the seconds and
    ``fix`` (exit status 1), or ``ok`` with the seconds (0)."""
    for problem in problems:
        print(problem)
    if problems:
        print(f"{failed} ({seconds:.1f} s): {fix}")
        return 1
    print(f"{ok} ({seconds:.1f} s)")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    """Write shards, or a published version's, in another project's file layout (``nbvdata.datasets.export``)."""
    from nbvdata.datasets.export import describe, export

    started = time.perf_counter()
    report = export(args.shards, args.format, args.out, args.root)
    print(f"{describe(report, args.format)} in {time.perf_counter() - started:.1f} s")
    return 0


def cmd_share(args: argparse.Namespace) -> int:
    """Write a published version's folder for the Hub or Zenodo (``nbvdata.datasets.share``)."""
    from nbvdata.datasets.share import describe, share

    started = time.perf_counter()
    report = share(args.manifest, args.out, args.root)
    print(f"{describe(report)} ({time.perf_counter() - started:.1f} s)")
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    """Render a shard sample, a saved grid (.npy), or the grid after scanning an object."""
    from nbvdata.core.views import view_sphere
    from nbvdata.view.render import render_state

    if args.grid is not None and args.grid.suffix in (".h5", ".hdf5"):
        return _show_sample(args)
    config = load_config(SimConfig, args.config, args.overrides)
    views = view_sphere(config.views)
    scanned: list[int] = []  # the views scanned from, drawn as green arrows (none for a grid file)
    if args.grid is not None:
        probabilities = _load_grid_file(args.grid, config.grid.size, args.index)
        title = args.grid.name
    else:
        from nbvdata.simulation.grid import OccupancyGrid
        from nbvdata.simulation.sensor import MeshScanner

        obj = _load_object(args, config)
        scanner = MeshScanner(obj.mesh, config.sensor)
        grid = OccupancyGrid(config.scene_grid)
        rng = np.random.default_rng(args.seed)
        scanned = _parse_indices(args.views, len(views))
        for index in scanned:
            grid.integrate(scanner.scan(views[index], rng, cloud=False), config.sensor.far)
        probabilities = grid.probabilities()
        title = f"{obj.source}, views {args.views}"
    highlight = None
    if args.highlight is not None:
        highlight = _parse_indices(str(args.highlight), len(views), "--highlight", "120")[0]
    out = render_state(probabilities, config.scene_grid.extent, args.out, views, highlight=highlight, title=title,
                       scanned=scanned, labels=("--highlight view", ""))
    print(f"wrote {out}")
    return 0


def _show_sample(args: argparse.Namespace) -> int:
    """Render sample ``--index`` of a shard with its NBV (red), the next best candidates (orange),
    the views its run scanned so far (green) and, when the shard holds point clouds, the state's cloud."""
    from nbvdata.core.views import ViewSet, look_at_rotations
    from nbvdata.schema.shards import Shard
    from nbvdata.view.render import render_state

    with Shard(args.grid) as shard:
        if not 0 <= args.index < len(shard):
            raise UsageError(f"--index {args.index}: {args.grid} holds {plural(len(shard), 'sample')} "
                             f"(0..{len(shard) - 1})")
        i = args.index
        probabilities = shard.grids(i)
        positions = shard["view_positions"]
        nbv, run, step = (int(shard.read(name, i)) for name in ("nbv_index", "run", "step"))
        scored = shard.has("gains") and shard.has("overlaps")  # imported shards carry no scores
        gains = shard.read("gains", i) if scored else None
        overlaps = shard.read("overlaps", i) if scored else None
        coverage = shard.read("coverage", i) if shard.has("coverage") else None
        points = shard.cloud(i) if shard.has("points") else None  # the state's cloud
        scanned = []  # the views its run scanned to reach it (a policy's off-view poses: -1, not drawn)
        if shard.has("last_view"):
            runs, steps, last = shard["run"], shard["step"], shard["last_view"]
            order = np.flatnonzero((runs == run) & (steps <= step))
            scanned = [int(v) for v in last[order[np.argsort(steps[order], kind="stable")]] if v >= 0]
        config = shard.info.config
        source = shard.info.meshes[0]["source"] if shard.info.meshes else args.grid.stem
    views = ViewSet(positions, look_at_rotations(positions))
    title = f"{source} run {run} step {step}: NBV {nbv}"
    ranked: list[int] = []
    if scored:
        valid = overlaps >= config["oracle"]["min_overlap"]
        ranked = [int(v) for v in np.argsort(-np.where(valid, gains, -1.0), kind="stable") if v != nbv and valid[v]]
        title += f" (+{100 * gains[nbv]:.1f}% of the observable surface, overlap {100 * overlaps[nbv]:.0f}%)"
    if coverage is not None:  # the shard's coverage: of the observable surface (docs/schema.md)
        title += f", observable coverage {100 * coverage[0]:.1f}% -> {100 * coverage[1]:.1f}%"
    # the shard's cube: fixed, or fitted to the object (null extent); imported shards publish none
    extent = (config.get("grid", {}).get("extent") or config.get("mesh", {}).get("object_size")
              or SimConfig().scene_grid.extent)
    out = render_state(probabilities, extent, args.out, views, highlight=nbv,
                       others=ranked[:args.top], title=title, points=points, scanned=scanned,
                       scanned_label="scanned by this state")
    print(f"wrote {out}")
    return 0


def _load_grid_file(path: Path, size: int, index: int) -> np.ndarray:
    """Grid ``index`` of a .npy file of one (n, n, n) grid or of (B, n, n, n) grids, checked as
    ``nbvtrain predict`` checks them -> (n, n, n) float32."""
    try:
        grids = check_grids(read_npy(path), size)
    except NpyError as error:
        raise UsageError(str(error)) from None
    except GridError as error:
        raise UsageError(f"{path}: {error}") from None
    if not 0 <= index < len(grids):
        raise UsageError(f"--index {index}: {path} holds {plural(len(grids), 'grid')} (0..{len(grids) - 1})")
    return grids[index]
