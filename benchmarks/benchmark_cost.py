"""What the default ``nbvtrain benchmark`` costs on this machine, and where the time goes.

Runs both default protocols (``paper``, ``objview``) with every default planner from 3 starts on
``--objects`` meshes spread evenly over the bench corpus (every k-th in name order), on
``--workers`` processes, and projects the wall-clock time to the whole corpus (issue 52's target:
both protocols, 201 objects, 3 starts, <= 45 min on 2 cores). The baseline, in the same process,
is ``nbvtrain evaluate`` of the same planners on the same objects (10 scans, the paper's setting,
set-cover floors included): the ratio says what the protocols' measurements add.

Where the time goes: one process (``--profile`` objects, one thread) with timers round the
phases: building the scene (ray-casting every candidate view for the oracle and the coverage
reference), the start's set-cover floor, each planner's decisions (the reconstructions' own
``seconds``), scanning and integrating, and the protocol's measurements (distances to the
reference points, the Chamfer distance, what every reachable view reaches).

    python benchmarks/benchmark_cost.py [--objects 10] [--workers 2] [--profile 2]
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from contextlib import contextmanager
from pathlib import Path

from nbvdata.core.views import view_sphere
from nbvdata.simulation.sources import mesh_sources
from nbvtrain.evaluation import benchmark as bench
from nbvtrain.evaluation import evaluate as evaluation
from nbvtrain.planners import build_planners, default_planners

CORPUS = Path(__file__).resolve().parents[2] / "shared" / "meshes" / "bench"


def spread(sources: list, count: int) -> list:
    """``count`` of ``sources`` evenly spread over them (every k-th)."""
    step = max(len(sources) / count, 1.0)
    return [sources[int(k * step)] for k in range(min(count, len(sources)))]


def planners_for(protocol: bench.Protocol):
    config = bench.protocol_config(protocol)
    planners, skipped = build_planners(default_planners(), config, view_sphere(config.views), {},
                                       foreign_views=protocol.snap)
    for message in skipped:
        print(f"  skipped: {message}")
    return config, planners


def wall_clock(sources: list, workers: int, total: int) -> dict[str, float]:
    """Seconds of each default protocol on ``sources`` and of the evaluate baseline."""
    seconds = {}
    for name in ("paper", "objview"):
        protocol = bench.load_protocol(name)
        config, planners = planners_for(protocol)
        began = time.perf_counter()
        report = bench.benchmark(sources, planners, config, protocol, starts=3, seed=0, workers=workers)
        seconds[name] = time.perf_counter() - began
        if report.failures:
            print(f"  {name}: {len(report.failures)} failed: {report.failures[:2]}")
        print(f"  benchmark --protocol {name}: {seconds[name]:7.1f} s, {seconds[name] / len(sources):5.2f} s per object "
              f"-> {seconds[name] / len(sources) * total / 60:5.1f} min for {total}")
    config, planners = planners_for(bench.load_protocol("paper"))
    began = time.perf_counter()
    evaluation.evaluate(sources, planners, config, scans=10, random_starts=2, seed=0, workers=workers)
    seconds["evaluate"] = time.perf_counter() - began
    print(f"  baseline nbvtrain evaluate (same planners, 3 starts, 10 scans): {seconds['evaluate']:7.1f} s")
    return seconds


@contextmanager
def timers(spent: dict[str, float]):
    """Wrap the benchmark's phases (module docstring) with timers adding into ``spent``."""
    from nbvdata.simulation.episode import Reconstruction
    from nbvdata.simulation.scene import Scene

    patched = []
    active: set[str] = set()  # a phase inside itself (scan calling scan_pose) counts once

    def wrap(owner, attribute: str, phase: str, static: bool = False) -> None:
        original = getattr(owner, attribute)
        function = original.__func__ if static else original

        def timed(*args, **kwargs):
            if phase in active:
                return function(*args, **kwargs)
            active.add(phase)
            began = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                spent[phase] += time.perf_counter() - began
                active.discard(phase)
        setattr(owner, attribute, classmethod(timed) if static else timed)
        patched.append((owner, attribute, original))

    wrap(Scene, "build", "scene build (candidate views cast, coverage reference)", static=True)
    wrap(bench, "start_floor", "set-cover floor of each start")
    wrap(Reconstruction, "scan", "scan and integrate")
    wrap(Reconstruction, "scan_pose", "scan and integrate")
    wrap(bench.RunMeasure, "add", "measure: distances per scan")
    wrap(bench.RunMeasure, "chamfer", "measure: Chamfer distance")
    wrap(bench.SurfaceMeasure, "reachable", "measure: what every reachable view reaches")
    try:
        yield
    finally:
        for owner, attribute, original in reversed(patched):
            setattr(owner, attribute, original)


def profile(sources: list) -> None:
    """Where one process spends a default benchmark's time on ``sources``."""
    evaluation.limit_threads(1)
    for name in ("paper", "objview"):
        protocol = bench.load_protocol(name)
        config, planners = planners_for(protocol)
        spent: dict[str, float] = defaultdict(float)
        began = time.perf_counter()
        with timers(spent):
            report = bench.benchmark(sources, planners, config, protocol, starts=3, seed=0, workers=1)
        total = time.perf_counter() - began
        decisions: dict[str, float] = defaultdict(float)
        for row in report.rows:
            decisions[row["planner"]] += row["seconds"]
        # the measurement of what every view reaches runs inside the first scan's distances
        spent["measure: distances per scan"] -= spent["measure: what every reachable view reaches"]
        print(f"\n  {name}: {total:.1f} s on {len(sources)} objects, one process")
        for phase, seconds in sorted(spent.items(), key=lambda item: -item[1]):
            print(f"    {phase:<52} {seconds:7.1f} s  {100 * seconds / total:4.0f} %")
        for planner, seconds in sorted(decisions.items(), key=lambda item: -item[1]):
            print(f"    decisions of {planner:<39} {seconds:7.1f} s  {100 * seconds / total:4.0f} %")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", type=Path, default=CORPUS, help="the corpus (default: the bench corpus)")
    parser.add_argument("--objects", type=int, default=10, help="objects timed on --workers (default 10)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--profile", type=int, default=2, help="objects profiled in one process (0: none)")
    args = parser.parse_args()
    if not args.meshes.is_dir():
        raise SystemExit(f"benchmark_cost: {args.meshes}: no such folder; pass --meshes DIR")
    sources, _ = mesh_sources(args.meshes)
    print(f"default benchmark: {len(sources)} objects in {args.meshes}; timing {args.objects} on {args.workers} workers")
    seconds = wall_clock(spread(sources, args.objects), args.workers, len(sources))
    projected = (seconds["paper"] + seconds["objview"]) / args.objects * len(sources) / 60
    print(f"  both protocols, {len(sources)} objects, 3 starts: {projected:.1f} min projected (target <= 45 min on 2 "
          f"cores); {(seconds['paper']) / seconds['evaluate']:.2f} x the evaluate baseline under paper")
    if args.profile:
        profile(spread(sources, args.profile))


if __name__ == "__main__":
    main()
