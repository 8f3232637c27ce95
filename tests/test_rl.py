"""Learning on the environment (nbvtrain.networks.rl, examples/rl_sb3.py): behaviour cloning learns the
oracle's choice on a tiny scene, collection is seeded and DAgger's states are the learner's, the
saved actor round-trips and refuses what is not one, MaskablePPO on the score network never
repeats a view, and the example's policy runs under nbvtrain evaluate."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

pytest.importorskip("gymnasium", reason="gymnasium (the [rl] extra) is not installed")

from nbvdata.core.config import SimConfig, load_config  # noqa: E402
from nbvdata.env import ReconstructEnv  # noqa: E402
from nbvdata.simulation.shapes import BUILTIN_SHAPES  # noqa: E402
from nbvtrain.networks import rl  # noqa: E402
from nbvtrain.networks.checkpoint import CheckpointError  # noqa: E402
from nbvtrain.planners.released import released_checkpoint  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs" / "smoke.yaml"
TWO = ["builtin:mug", "builtin:ring"]
LONGER = ["episode.max_scans=8"]


@pytest.fixture(scope="module")
def config() -> SimConfig:
    return load_config(SimConfig, SMOKE)


@pytest.fixture(scope="module")
def env(config) -> ReconstructEnv:
    return ReconstructEnv(TWO, config, LONGER, info_scores=True)


class TinyPolicy(nn.Module):
    """(B, n, n, n) grids and (B, V) view states -> (B, V) logits: the unknown voxels averaged
    over 8^3 blocks and the view state, through one hidden layer."""

    def __init__(self, views: int):
        super().__init__()
        self.pool = nn.AvgPool3d(8)
        self.body = nn.Sequential(nn.Linear(64 + views, 128), nn.ReLU(), nn.Linear(128, views))

    def forward(self, grids: torch.Tensor, taken: torch.Tensor) -> torch.Tensor:
        unknown = self.pool((grids == 0.5).float()[:, None]).flatten(1)
        return self.body(torch.cat([unknown, taken], dim=1))


def test_behaviour_cloning_learns_the_oracles_choice_on_a_tiny_scene(env):
    """60 views, two shapes: after cloning 40 episodes of the oracle's, the policy picks the
    oracle's view on unseen episodes (other starts) far more often than chance (1 / allowed views)."""
    torch.manual_seed(0)
    train = rl.collect(env, None, 40, seed=0, expert_share=1.0)
    held_out = rl.collect(env, None, 15, seed=1, expert_share=1.0)
    policy = TinyPolicy(env.action_space.n)
    before = rl.agreement(policy, held_out)
    losses = rl.clone(policy, policy.parameters(), train, epochs=60, batch_size=32, lr=3e-3)
    after = rl.agreement(policy, held_out)
    chance = float(np.mean(1.0 / held_out.masks.sum(axis=1)))
    assert len(train) > 150 and losses[-1] < 0.5 * losses[0]
    assert after > 8 * chance and after > before + 0.1, (before, after, chance)
    assert np.all(held_out.masks[np.arange(len(held_out)), held_out.labels])  # the oracle's view is allowed


def test_collection_is_seeded_and_dagger_states_are_the_learners(env):
    first = lambda observation, mask: int(np.flatnonzero(mask)[0])  # noqa: E731  (a deterministic learner)
    a = rl.collect(env, first, 6, seed=3, expert_share=0.0)
    b = rl.collect(env, first, 6, seed=3, expert_share=0.0)
    assert all(np.array_equal(x, y) for x, y in zip(a.arrays(), b.arrays()))
    # the learner acted: each next state of an episode has its choice scanned, often not the oracle's
    chosen = [int(np.flatnonzero(mask)[0]) for mask in a.masks]
    follows = [bool(a.taken[i + 1, chosen[i]]) for i in range(len(a) - 1) if a.taken[i + 1].sum() > a.taken[i].sum()]
    assert follows and all(follows)
    assert np.mean(np.array(chosen) != a.labels) > 0.5
    oracle = rl.collect(env, first, 6, seed=3, expert_share=1.0)
    assert not np.array_equal(oracle.taken, a.taken[:len(oracle)]) or len(oracle) != len(a)
    with pytest.raises(ValueError, match="expert_share"):
        rl.collect(env, first, 1, seed=0, expert_share=1.5)
    with pytest.raises(ValueError, match="info_scores=True"):
        rl.collect(ReconstructEnv(TWO, env.config), first, 1, seed=0)


def test_a_budget_stops_collection_and_cloning(env):
    calls = []
    data = rl.collect(env, None, 50, seed=0, stop=lambda: len(calls) > 2 or calls.append(1))
    assert 1 <= len({i for i in range(len(data))}) and len(data) < 4 * 8  # 3 episodes at most
    policy = TinyPolicy(env.action_space.n)
    losses = rl.clone(policy, policy.parameters(), data, epochs=50, batch_size=4, stop=lambda: True)
    assert len(losses) == 1


def test_a_saved_actor_gives_the_same_logits_and_foreign_files_are_refused(env, tmp_path):
    views = env.views.unit_positions
    features = rl.ScoreFeatures(env.observation_space, views)
    head = nn.Linear(len(views), len(views))
    rl.identity_head(head, 2.0)
    rl.save_actor(tmp_path / "actor.pt", features, head, {"stage": "test"})
    logits, about = rl.load_actor(tmp_path / "actor.pt")
    observation, _ = env.reset(seed=0)
    grid = torch.from_numpy(observation["grid"])[None]
    taken = torch.from_numpy(observation["taken"]).float()[None]
    with torch.no_grad():
        expected = 2.0 * features({"grid": grid, "taken": taken})
        assert torch.allclose(logits(grid, taken), expected, atol=1e-5) and about == {"stage": "test"}
    (tmp_path / "other.pt").write_bytes(b"not a checkpoint")
    torch.save({"weights": torch.zeros(3)}, tmp_path / "foreign.pt")
    for name in ("other.pt", "foreign.pt", "missing.pt"):
        with pytest.raises(CheckpointError, match=f"{name}: .*python examples/rl_sb3.py"):
            rl.load_actor(tmp_path / name)
    with pytest.raises(CheckpointError, match="not an nbvscore-fc3 network for these 60 candidate views"):
        rl.score_network(views, released_checkpoint("scores"))


def test_the_released_score_network_starts_the_policy_at_its_own_choice():
    """Default scene: ScoreFeatures on the released weights with the identity head picks what the
    released network scores highest (the ``scores`` planner's choice)."""
    from nbvdata.core.views import view_sphere
    from nbvtrain.networks.checkpoint import load_checkpoint, model_from
    views = view_sphere(SimConfig().views).unit_positions
    space = {"taken": type("Space", (), {"n": len(views)})()}
    features = rl.ScoreFeatures(space, views, released_checkpoint("scores"))
    released = model_from(load_checkpoint(released_checkpoint("scores")), released_checkpoint("scores")).eval()
    grids = torch.full((2, 32, 32, 32), 0.5)
    grids[0, 10:20, 10:20, 5:15] = 0.9
    taken = torch.zeros(2, len(views))
    taken[0, [3, 40]] = 1
    with torch.no_grad():
        assert torch.allclose(features({"grid": grids, "taken": taken}), released(grids[:, None], taken), atol=1e-5)


def _example():
    """examples/rl_sb3.py as a module (it needs sb3-contrib)."""
    pytest.importorskip("sb3_contrib", reason='sb3-contrib (the [rl] extra) is not installed: pip install -e ".[rl]"')
    import importlib.util
    spec = importlib.util.spec_from_file_location("rl_sb3", ROOT / "examples" / "rl_sb3.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_maskable_ppo_on_the_score_network_never_repeats_a_view(config):
    """The example's MaskablePPO (score network, identity head): it starts at the network's own
    scores, learns a rollout, and its sampled actions under the environment's masks never repeat."""
    example = _example()
    env = ReconstructEnv(TWO, config, ["episode.max_scans=12", "episode.min_gain=0"], info_scores=True)
    model = example.new_model(env, env.views.unit_positions, None, gamma=0.5, lr=1e-4, seed=0)
    observation, _ = env.reset(seed=0)
    grid = torch.from_numpy(observation["grid"])[None]
    taken = torch.from_numpy(observation["taken"]).float()[None]
    with torch.no_grad():
        features = model.policy.features_extractor({"grid": grid, "taken": taken})
        assert torch.allclose(example.actor_logits(model.policy)(grid, taken), features, atol=1e-6)
    model.learn(256)
    assert model.num_timesteps >= 256
    for seed in range(3):
        observation, info = env.reset(seed=seed)
        views, done = [info["view"]], False
        while not done:
            action, _ = model.predict(observation, action_masks=env.action_masks(), deterministic=False)
            observation, _, terminated, truncated, info = env.step(int(action))
            views.append(info["view"])
            done = terminated or truncated
        assert len(views) > 4 and len(set(views)) == len(views), views


def test_the_examples_policy_runs_under_nbvtrain_evaluate(config, tmp_path, monkeypatch):
    from nbvtrain.cli import main
    _example()  # the file imports (sb3-contrib installed)
    folder = tmp_path / "meshes"
    folder.mkdir()
    for name in ("mug", "ring"):
        BUILTIN_SHAPES[name]().export(folder / f"{name}.obj")
    env = ReconstructEnv(TWO, config)
    views = env.views.unit_positions
    head = nn.Linear(len(views), len(views))
    rl.identity_head(head)
    (tmp_path / "rl").mkdir()
    rl.save_actor(tmp_path / "rl" / "actor.pt", rl.ScoreFeatures(env.observation_space, views), head, {})
    monkeypatch.setenv("NBV_RL_DIR", str(tmp_path / "rl"))
    policy = f"{ROOT / 'examples' / 'rl_sb3.py'}:policy"
    out = tmp_path / "eval"
    assert main(["evaluate", "--meshes", str(folder), "--planners", f"{policy},random", "--scans", "4",
                 "--config", str(SMOKE), "--out", str(out), "--no-progress"]) == 0
    with open(out / "coverage.csv") as handle:
        rows = [row for row in csv.DictReader(handle) if row["planner"] == policy]
    assert len(rows) >= 2 * 4 and all(0 < float(row["coverage"]) <= 1 for row in rows)
    monkeypatch.setenv("NBV_RL_DIR", str(tmp_path / "nowhere"))
    assert main(["evaluate", "--meshes", str(folder), "--planners", f"{policy},random", "--scans", "3",
                 "--config", str(SMOKE), "--out", str(tmp_path / "eval2"), "--no-progress"]) != 0


def test_without_the_rl_extra_the_example_says_the_install_in_one_line():
    import subprocess
    import sys
    code = ("import sys, runpy\n"
            "sys.modules['sb3_contrib'] = None  # as if not installed\n"
            "sys.argv = ['rl_sb3.py', '--help']\n"
            f"runpy.run_path({str(ROOT / 'examples' / 'rl_sb3.py')!r}, run_name='__main__')\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr.strip().splitlines() == ['examples/rl_sb3.py needs sb3-contrib and stable-baselines3: '
                                               'pip install -e ".[rl]"'], done.stderr


def test_the_example_runs_from_a_clone_on_the_built_in_shapes(tmp_path):
    """Issue 58: from a clone (no ../shared/meshes) the example stopped with a ManifestError
    traceback, with the built-in shapes' manifest with a TypeError, and its --help mid-sentence.
    From a copy of a clone's files: the default says in one line what it needs and how to run on the
    built-in shapes; that runs the whole recipe in a small budget and saves the chosen actor."""
    import shutil
    import subprocess
    import sys

    clone = tmp_path / "clone" / "nbv-regression"  # no ../shared beside it
    for name in ("examples/rl_sb3.py", "manifests/train-meshes-1.2.0.json", "manifests/builtin-shapes-1.3.0.json"):
        (clone / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ROOT / name, clone / name)

    def run(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "examples/rl_sb3.py", *argv], capture_output=True, text=True,
                              timeout=600, cwd=clone)

    import resource

    def cpu_seconds() -> float:
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        return usage.ru_utime + usage.ru_stime

    shown = run("--help")
    assert shown.returncode == 0 and "then MaskablePPO (sb3-contrib) on" in " ".join(shown.stdout.split())
    refused = run()
    assert refused.returncode == 1 and refused.stdout == ""
    assert len(refused.stderr.strip().splitlines()) == 1 and "Traceback" not in refused.stderr, refused.stderr
    assert "../shared/meshes" in refused.stderr and "--manifest manifests/builtin-shapes-1.3.0.json" in refused.stderr
    before = cpu_seconds()
    done = run("--manifest", "manifests/builtin-shapes-1.3.0.json", "--minutes", "0.5", "--episodes", "2",
               "--dagger-rounds", "1", "--gammas", "0.5", "--val-starts", "1", "--out", str(tmp_path / "rl"))
    assert done.returncode == 0, done.stderr
    assert cpu_seconds() - before <= 0.5 * 60, "over its budget of CPU minutes"  # issue 66: --minutes 2 took 2.21
    assert done.stdout.startswith("4 training meshes, 1 validation mesh x 1 start; ")
    with open(tmp_path / "rl" / "curve.csv") as handle:
        stages = {row["stage"] for row in csv.DictReader(handle)}
    assert {"start", "clone", "dagger1", "ppo-g0.5"} <= stages
    rl.load_actor(tmp_path / "rl" / "actor.pt")
