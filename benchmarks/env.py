"""Benchmark: steps per second of the Gymnasium environment (``nbvdata.env``) against the
generator's own states per second, in the same run.

For the built-in shapes, then the first ``--train-meshes`` meshes of ``../shared/meshes/train/``
(skipped when absent), at the default settings (500 views, 176 x 144 sensor, 16,384 reference
points, up to 10 scans):

1. generator: the units of ``nbvdata generate`` (``--runs`` runs per mesh), each run as a parallel
   worker runs it (one thread); its cost per state is the time of its runs, grid encoding and
   shard writing (the "runs", "encode" and "write" phases) per labelled state: scene builds left out.
2. env replay: one environment (``info_scores=True``) replays every generated run: the same mesh
   and start view, the oracle's moves, so the same scans. Its cost per state is the replay's time
   per labelled state (a reset or step per state, plus the step into a run's terminal state),
   the scenes built ahead. Target: within 1.5x of the generator's.
3. one env and ``AsyncVectorEnv`` of 2 (forkserver): ``--episodes`` episodes per
   environment following the oracle from seeded starts, after one reset per mesh (scene builds
   left out); environment steps per second, the vector env's counting both.
4. one env, random candidate views on the first mesh once every view was scanned (the view cache
   full, as it soon is for a learner on a fixed set of meshes): ``10 * --episodes`` episodes.

    python benchmarks/env.py [--runs 3] [--train-meshes 4] [--episodes 12] [--set KEY=VALUE ...]

Both sides pay for the first scan from each view of a mesh (a few ms to 100+ ms on a busy
machine; cached after), so the figures hold that cost as a reinforcement learner meets it early on.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import gymnasium
import numpy as np

from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.generate import plan_units, run_unit
from nbvdata.env import ReconstructEnv
from nbvdata.schema.shards import Shard
from nbvdata.simulation.episode import start_view
from nbvdata.simulation.mesh import find_meshes
from nbvdata.simulation.sources import builtin_sources, mesh_sources

TRAIN = Path(__file__).resolve().parents[2] / "shared" / "meshes" / "train"


def _generator(sources, config: SimConfig, out: Path) -> tuple[float, int]:
    """(seconds of runs + encode + write, labelled states) of the job's units, each run as a
    parallel worker runs it (``run_unit``, one thread), into ``out``."""
    results = [run_unit(unit, config, out, threads=1) for unit in plan_units(sources, config)]
    failures = [result.error for result in results if result.error]
    if failures:
        raise SystemExit(f"meshes failed: {failures}")
    seconds = sum(r.seconds.get(phase, 0.0) for r in results for phase in ("runs", "encode", "write"))
    return seconds, sum(result.samples for result in results)


def _replay(env: ReconstructEnv, sources, config: SimConfig, out: Path) -> tuple[float, int, int]:
    """(seconds, states, steps) of replaying every run of the shards in ``out`` through ``env``."""
    for index in range(len(sources)):
        env._scene(index)  # built ahead, as the generator's scene phase is left out
    seconds = states = steps = 0
    for index, source in enumerate(sources):
        for path in sorted(out.glob(f"{source.stem}-{source.mesh_id[:12]}-*.h5")):
            with Shard(path) as shard:
                runs, moves = shard["run"], shard["nbv_index"]
            for run in np.unique(runs):
                mine = moves[runs == run]
                start = start_view(config.episode.seed, source.mesh_id, config.views.count, int(run))
                began = time.perf_counter()
                _, info = env.reset(options={"mesh": index, "start_view": start})
                ended = False
                for move in mine[:len(mine) if len(mine) < config.episode.max_scans else -1]:
                    _, _, terminated, truncated, info = env.step(int(move))
                    steps += 1
                    ended = terminated or truncated
                seconds += time.perf_counter() - began
                states += len(mine)
                assert ended or len(mine) == config.episode.max_scans
    return seconds, states, steps


def _episodes_single(make, meshes: int, episodes: int) -> tuple[float, int]:
    """(seconds, steps) of ``episodes`` oracle-following episodes of one environment."""
    env = make()
    for mesh in range(meshes):
        env.reset(options={"mesh": mesh})
    steps, began = 0, time.perf_counter()
    for episode in range(episodes):
        _, info = env.reset(seed=episode)
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(max(info["nbv"], 0))
            steps, done = steps + 1, terminated or truncated
    return time.perf_counter() - began, steps


def _episodes_vector(make, meshes: int, episodes: int) -> tuple[float, int]:
    """(seconds, steps of both) of ``episodes`` oracle-following episodes in each of 2 processes."""
    vector = gymnasium.vector.AsyncVectorEnv([make, make], context="forkserver")
    try:
        for mesh in range(meshes):
            vector.reset(options={"mesh": mesh})
        began = time.perf_counter()
        _, infos = vector.reset(seed=[1000, 2000])
        finished, steps, previous_done = np.zeros(2, dtype=int), 0, np.zeros(2, dtype=bool)
        while finished.min() < episodes:
            _, _, terminated, truncated, infos = vector.step(np.maximum(infos["nbv"], 0))
            steps += int((~previous_done).sum())  # a step after an episode's end only resets
            previous_done = terminated | truncated
            finished += previous_done
        return time.perf_counter() - began, steps
    finally:
        vector.close()


def _warm_random(make, episodes: int) -> tuple[float, int]:
    """(seconds, steps) of ``episodes`` random-view episodes on the first mesh after every
    candidate view was scanned once (the view cache full): a learner's steady state."""
    env = make()
    views, view = env.action_space.n, 0
    while view < views:
        env.reset(options={"mesh": 0})
        done = False
        while not done and view < views:
            _, _, terminated, truncated, _ = env.step(view)
            view, done = view + 1, terminated or truncated
    rng, steps, began = np.random.default_rng(0), 0, time.perf_counter()
    for episode in range(episodes):
        env.reset(seed=episode, options={"mesh": 0})
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(int(rng.integers(views)))
            steps, done = steps + 1, terminated or truncated
    return time.perf_counter() - began, steps


class _Make:
    """A picklable environment factory (forkserver children build their own)."""

    def __init__(self, meshes, config: SimConfig):
        self.meshes, self.config = meshes, config

    def __call__(self) -> ReconstructEnv:
        return ReconstructEnv(self.meshes, self.config, info_scores=True)


def _bench(label: str, meshes, sources, args) -> None:
    config = load_config(SimConfig, None, args.overrides + [f"episode.runs_per_mesh={args.runs}"])
    with tempfile.TemporaryDirectory(prefix="nbv-bench-env-") as folder:
        gen_seconds, gen_states = _generator(sources, config, Path(folder))
        env = ReconstructEnv(meshes, config, info_scores=True)
        assert env.sources == sources  # the generator's meshes, in its order
        env_seconds, env_states, env_steps = _replay(env, sources, config, Path(folder))
    if env_states != gen_states:
        raise SystemExit(f"the replay visited {env_states} states, the generator labelled {gen_states}")
    gen_ms, env_ms = 1e3 * gen_seconds / gen_states, 1e3 * env_seconds / env_states
    verdict = "meets" if env_ms <= 1.5 * gen_ms else "MISSES"
    print(f"\n{label}: {len(sources)} meshes x {args.runs} runs = {gen_states} labelled states")
    print("| workload | states or steps | seconds | per second | ms each |\n|---|---|---|---|---|")
    print(f"| generator (1 worker): states | {gen_states} | {gen_seconds:.2f} | {gen_states / gen_seconds:.0f} | "
          f"{gen_ms:.2f} |")
    print(f"| env replaying its runs: states | {env_states} | {env_seconds:.2f} | {env_states / env_seconds:.0f} | "
          f"{env_ms:.2f} |")
    for name, run in (("one env", _episodes_single), ("vector env of 2", _episodes_vector)):
        seconds, steps = run(_Make(meshes, config), len(sources), args.episodes)
        print(f"| {name}: oracle episodes, steps | {steps} | {seconds:.2f} | {steps / seconds:.0f} | "
              f"{1e3 * seconds / steps:.2f} |")
    seconds, steps = _warm_random(_Make(meshes, config), 10 * args.episodes)
    print(f"| one env: random views, every view scanned before ({sources[0].name}), steps | {steps} | "
          f"{seconds:.2f} | {steps / seconds:.0f} | {1e3 * seconds / steps:.2f} |")
    print(f"env cost per state / generator's: {env_ms / gen_ms:.2f}x ({verdict} the target <= 1.5x)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="generator runs per mesh (3)")
    parser.add_argument("--train-meshes", type=int, default=4, help="meshes of shared/meshes/train (4; 0 = none)")
    parser.add_argument("--episodes", type=int, default=12, help="episodes per environment in workload 3 (12)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="a setting other than the default, as nbvdata generate --set (for a quick try)")
    args = parser.parse_args()
    began = time.perf_counter()
    _bench("built-in shapes", None, builtin_sources(), args)
    if args.train_meshes and TRAIN.is_dir():
        files = find_meshes(TRAIN)[:args.train_meshes]
        sources = [source for path in files for source in mesh_sources(path)[0]]
        _bench(f"train/ meshes ({', '.join(p.name for p in files)})", [str(p) for p in files], sources, args)
    elif args.train_meshes:
        print(f"\n{TRAIN} absent: train/ meshes skipped")
    print(f"\nbenchmark total {time.perf_counter() - began:.0f} s")


if __name__ == "__main__":
    main()
