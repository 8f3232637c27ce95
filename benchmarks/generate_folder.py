"""Benchmark: ``nbvdata generate`` on a folder of meshes, against the code of another git revision.

The same job (meshes, settings, workers) runs twice in this benchmark, each in a fresh process:
with the code of ``--baseline`` (checked out into a temporary git worktree) and with the code of
this checkout. It prints both wall times, states per second and where the workers' time went
(the shard's phases: scene, runs, encode, write), then compares the two jobs' shards array by
array and attribute by attribute (all but the package version).

    python benchmarks/generate_folder.py [--meshes ../shared/meshes/train] [--baseline 62dc09d]
        [--workers 2] [--limit N] [--set sensor.noise_std=0.002 ...]

Targets (issue 16): the shared train/ folder with default settings and 2 workers in <= 150 s on
an idle 2-core machine; with range noise (every scan live), >= 2x the baseline's states/s.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TRAIN = ROOT.parent / "shared" / "meshes" / "train"
# Today's code when issue 16 was taken up: the job as it was before the work on speed.
BASELINE = "62dc09d"

# Run in a child process whose PYTHONPATH starts with the code to time; the API it uses
# (mesh_sources, load_config, generate) is the same in every revision this compares.
JOB = r"""
import json, sys
from collections import defaultdict
from pathlib import Path
import nbvdata
from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.generate import generate
from nbvdata.simulation.sources import mesh_sources

meshes, out, limit, overrides = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), sys.argv[4:]
sources, failures = mesh_sources(meshes)
sources = sources[:limit] if limit else sources
config = load_config(SimConfig, None, overrides)
generate(sources[:1], out / "warm-up", load_config(SimConfig, None, overrides + ["episode.runs_per_mesh=1",
         "generate.workers=1"]), show_progress=False)  # compile (or load) the numba kernels first
report = generate(sources, out / "shards", config, show_progress=False)
phases = defaultdict(float)
for result in report.done:
    for phase, seconds in result.seconds.items():
        phases[phase] += seconds
print(json.dumps({"code": str(Path(nbvdata.__file__).parent), "samples": report.samples,
                  "seconds": report.seconds, "meshes": len(report.done),
                  "failures": len(report.failures), "phases": phases}))
"""


def _job(code: Path, meshes: Path, out: Path, limit: int, overrides: list[str]) -> dict:
    """Run the job with the package at ``code``; its report as a dict."""
    env = dict(os.environ, PYTHONPATH=f"{code}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    done = subprocess.run([sys.executable, "-c", JOB, str(meshes), str(out), str(limit), *overrides],
                          env=env, capture_output=True, text=True, cwd=code)
    if done.returncode != 0:
        raise SystemExit(f"the job with the code in {code} failed:\n{done.stderr[-3000:]}")
    report = json.loads(done.stdout.strip().splitlines()[-1])
    if Path(report["code"]) != code / "nbvdata":
        raise SystemExit(f"the job imported {report['code']}, not the code in {code}")
    return report


def _print(label: str, report: dict) -> None:
    phases, busy = report["phases"], sum(report["phases"].values())
    print(f"{label}: {report['samples']:,} states from {report['meshes']} meshes in {report['seconds']:.1f} s "
          f"wall = {report['samples'] / report['seconds']:.1f} states/s ({report['failures']} failed)")
    print("  worker time: " + ", ".join(f"{phase} {seconds:.1f} s ({100 * seconds / busy:.0f}%)"
                                        for phase, seconds in phases.items() if seconds >= 0.05)
          + f"; total {busy:.1f} s")


def _differences(before: Path, after: Path) -> list[str]:
    """Shards, arrays and attributes (but the package version) that differ between two folders."""
    names = sorted(p.name for p in before.glob("*.h5"))
    problems = [] if names == sorted(p.name for p in after.glob("*.h5")) else ["the shard names differ"]
    for name in names:
        if not (after / name).exists():
            continue
        with h5py.File(before / name, "r") as a, h5py.File(after / name, "r") as b:
            if sorted(a) != sorted(b):
                problems.append(f"{name}: other arrays")
            problems += [f"{name}: {key}" for key in sorted(set(a) & set(b))
                         if a[key].dtype != b[key].dtype or not np.array_equal(a[key][()], b[key][()])]
            attrs = set(a.attrs) | set(b.attrs)
            problems += [f"{name}: attribute {key}" for key in sorted(attrs - {"package_version"})
                         if key not in a.attrs or key not in b.attrs
                         or not np.array_equal(np.asarray(a.attrs[key]), np.asarray(b.attrs[key]))]
    return problems


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", type=Path, default=TRAIN, help="folder, mesh file or .txt list")
    parser.add_argument("--baseline", default=BASELINE, help="git revision of the code to compare against")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--limit", type=int, default=0, help="only the first N meshes (0 = all)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="a setting, as nbvdata generate --set")
    args = parser.parse_args()
    if not args.meshes.exists():
        raise SystemExit(f"{args.meshes} absent: pass --meshes with a folder of meshes")
    overrides = args.overrides + [f"generate.workers={args.workers}"]
    print(f"{args.meshes}{f' (first {args.limit})' if args.limit else ''}, {' '.join(overrides)}; "
          f"baseline: the code at {args.baseline}")
    with tempfile.TemporaryDirectory(prefix="nbv-bench-") as tmp:
        tmp = Path(tmp)
        added = subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "--quiet",
                                str(tmp / "baseline"), args.baseline], capture_output=True, text=True)
        if added.returncode != 0:
            raise SystemExit(f"cannot check out {args.baseline} ({added.stderr.strip()}): pass --baseline with a "
                             "revision of this clone (a shallow clone lacks the old ones: git fetch --unshallow)")
        try:
            before = _job(tmp / "baseline", args.meshes.resolve(), tmp / "before", args.limit, overrides)
            after = _job(ROOT, args.meshes.resolve(), tmp / "after", args.limit, overrides)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tmp / "baseline")],
                           check=False)
        _print(f"before ({args.baseline})", before)
        _print("after (this checkout)", after)
        problems = _differences(tmp / "before" / "shards", tmp / "after" / "shards")
    print(f"speed-up: {before['seconds'] / after['seconds']:.2f}x wall, "
          f"{after['samples'] / after['seconds'] / (before['samples'] / before['seconds']):.2f}x states/s")
    if problems:
        print(f"the shards DIFFER ({len(problems)}): " + "; ".join(problems[:10]))
    else:
        print("the shards are the same, array by array and attribute by attribute (but package_version)")


if __name__ == "__main__":
    main()
