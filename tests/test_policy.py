"""Learned-policy rollouts (``nbvdata generate --policy``): the runs take exactly the moves of
``nbvtrain evaluate``'s planner for the checkpoint, every state is labelled exactly, the shards
record the checkpoint, and nbvdata itself still runs without torch."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the train extra is not installed: pip install -e '.[train]'")

from nbvdata.cli import main  # noqa: E402
from nbvdata.core.config import SimConfig, load_config  # noqa: E402
from nbvdata.core.views import view_sphere  # noqa: E402
from nbvdata.datasets.generate import generate  # noqa: E402
from nbvdata.schema.shards import Shard  # noqa: E402
from nbvdata.simulation.episode import Reconstruction, run_seed, scene_rng, start_view  # noqa: E402
from nbvdata.simulation.policy import PolicySource  # noqa: E402
from nbvdata.simulation.scene import Scene  # noqa: E402
from nbvdata.simulation.shapes import builtin_object  # noqa: E402
from nbvdata.simulation.sources import builtin_sources  # noqa: E402
from nbvtrain.evaluation.evaluate import reconstruct  # noqa: E402
from nbvtrain.networks.config import TrainConfig  # noqa: E402
from nbvtrain.networks.models import build_model  # noqa: E402
from nbvtrain.networks.train import save_training_state  # noqa: E402
from nbvtrain.planners import LearnedPlanner, Observation  # noqa: E402
from conftest import about  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs" / "smoke.yaml"
TASKS = {"nbvnet-3-3": "regression", "nbvnet-class": "classification", "nbvscore-3": "scores"}


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory) -> dict[str, Path]:
    """Untrained (seeded) networks saved as nbvtrain checkpoints: tiny policies."""
    folder = tmp_path_factory.mktemp("checkpoints")
    units = view_sphere(_config().views).unit_positions
    paths = {}
    for seed, name in enumerate(("nbvnet-3-3", "nbvnet-class", "nbvscore-3", "nbvnet-3-3")):
        torch.manual_seed(seed)
        model = build_model(name, views=units if name == "nbvscore-3" else None)
        paths[name if seed < 3 else "other"] = path = folder / f"{name}-{seed}.pt"
        save_training_state(path, model, torch.optim.Adam(model.parameters()), TrainConfig(model=name), [], 0, 0.4, None, units)
    return paths


@pytest.fixture(scope="module")
def mug():
    return [source for source in builtin_sources() if source.stem == "mug"]


def _config(*overrides: str) -> SimConfig:
    return load_config(SimConfig, SMOKE, ["generate.workers=1", *overrides])


def _arrays(folder: Path) -> dict[str, np.ndarray]:
    (path,) = folder.glob("*.h5")
    with Shard(path) as shard:
        arrays = {name: shard[name] for name in shard.file}
        arrays["probabilities"] = shard.grids()
        arrays["policy"] = json.loads(shard.file.attrs["policy"])
    return arrays


@pytest.mark.parametrize("network", list(TASKS))
def test_a_rollout_takes_the_planners_moves_and_labels_them_exactly(tmp_path, checkpoints, mug, network):
    config = _config("episode.runs_per_mesh=3")
    checkpoint = checkpoints[network]
    generate(mug, tmp_path, config, show_progress=False, policy=PolicySource.from_path(checkpoint))
    arrays = _arrays(tmp_path)
    mesh_id = mug[0].mesh_id
    scene = Scene.build(builtin_object("mug", config.mesh), config, scene_rng(0, mesh_id))
    planner = LearnedPlanner(checkpoint, config.views.radius, TASKS[network], scene.views)
    seen = np.array([scene.coverage.covered_by(scene.scanner.scan(scene.views[v]).hit_points)
                     for v in range(len(scene.views))])  # live scans: no bit matrix, no cache
    counts, observable = seen.sum(axis=1), seen.any(axis=0).sum()
    for run in range(3):
        rows = np.flatnonzero(arrays["run"] == run)
        first = start_view(0, mesh_id, len(scene.views), run)
        assert arrays["last_view"][rows[0]] == first and (arrays["move"][rows[:-1]] == 2).all()
        taken = arrays["next_pose"][rows][arrays["move"][rows] >= 0]
        moved = arrays["next_view"][rows][arrays["move"][rows] >= 0]
        assert len(taken) >= 2
        if TASKS[network] == "scores":  # candidate views, recorded as such: the view state stays known
            assert (moved >= 0).all() and np.array_equal(scene.views.positions[moved], taken[:, :3])
        else:
            assert (arrays["next_view"][rows] == -1).all()  # poses, no candidate views

        # the moves: nbvtrain evaluate's trajectory from the same start
        trajectory = reconstruct(scene, planner, first, len(taken) + 1, run_seed(0, mesh_id, run))
        assert np.array_equal(taken[:, :3], [[row["x"], row["y"], row["z"]] for row in trajectory[1:]])

        # the states and labels: the run replayed with live scans, checked by an independent count
        live = Reconstruction(scene, None, np.random.default_rng(0))
        live.scan_pose(scene.views[first])
        poses, covered = [scene.views[first]], seen[first].copy()
        for step, i in enumerate(rows):
            assert np.array_equal(arrays["probabilities"][i], live.grid.probabilities())
            new = (seen & ~covered).sum(axis=1)
            overlaps = np.where(counts > 0, (counts - new) / np.maximum(counts, 1), 0.0)
            gains = new / observable
            valid = (overlaps >= config.oracle.min_overlap) & (new > 0) & (gains >= config.episode.min_gain)
            assert arrays["nbv_index"][i] == int(np.argmax(np.where(valid, gains, -1.0)))
            assert np.array_equal(arrays["gains"][i], gains.astype(np.float32))
            if arrays["move"][i] < 0:
                break
            pose = planner.next_pose(Observation(live.grid.probabilities(), tuple(poses)))
            assert np.array_equal(arrays["next_pose"][i], pose.xyzypr)
            covered |= scene.coverage.covered_by(scene.scanner.scan(pose).hit_points)
            live.scan_pose(pose)
            poses.append(pose)
            if step + 1 < len(rows):  # -1: the last scan was no candidate view
                expected = moved[step] if TASKS[network] == "scores" else -1
                assert arrays["last_view"][rows[step + 1]] == expected
    digest = hashlib.sha256(checkpoint.read_bytes()).hexdigest()
    assert arrays["policy"] == {"sha256": digest, "network": f"{network} epoch 0"}


def test_rollouts_are_the_same_with_one_and_two_workers_and_mix_in_the_oracle(tmp_path, checkpoints):
    sources = builtin_sources()[:2]
    policy = PolicySource.from_path(checkpoints["nbvnet-3-3"])
    digests = {}
    for workers in (1, 2):
        out = tmp_path / f"workers{workers}"
        generate(sources, out, _config(f"generate.workers={workers}", "generate.runs_per_shard=1",
                                       "episode.runs_per_mesh=4", "episode.oracle_mix=0.5"),
                 show_progress=False, policy=policy)
        digests[workers] = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(out.iterdir())
                           if p.is_file() and not p.name.startswith(".")}
    assert len(digests[1]) == 2 * 4 + 2 and digests[1] == digests[2]  # shards, config.yaml and policy.yaml
    moves = []
    for path in sorted((tmp_path / "workers1").glob("*.h5")):
        with Shard(path) as shard:
            move, next_view, nbv = shard["move"], shard["next_view"], shard["nbv_index"]
        assert np.array_equal(next_view[move == 0], nbv[move == 0]) and (next_view[move == 2] == -1).all()
        moves.append(move)
    moves = np.concatenate(moves)
    assert set(moves.tolist()) == {-1, 0, 2}


def test_a_folder_holds_the_runs_of_one_policy(tmp_path, checkpoints, capsys):
    argv = ["generate", "--out", str(tmp_path), "--config", str(SMOKE), "--runs-per-mesh", "1", "--workers", "1",
            "--no-progress"]
    assert main([*argv, "--policy", str(checkpoints["nbvnet-3-3"])]) == 0
    assert "policy followed: nbvnet-3-3 epoch 0" in (main(["inspect", str(tmp_path)]) == 0 and capsys.readouterr().out)
    digest = hashlib.sha256(checkpoints["nbvnet-3-3"].read_bytes()).hexdigest()
    for extra, message in (([], "follow the policy nbvnet-3-3 epoch 0 (sha256 "),
                           (["--policy", str(checkpoints["other"])], f"checkpoint of sha256 {digest} to resume")):
        assert main([*argv, *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err
    assert main([*argv, "--policy", str(checkpoints["nbvnet-3-3"])]) == 0
    assert "6 shards were already there" in capsys.readouterr().out

    from nbvdata.datasets.publish import publish

    card = publish(tmp_path, "rollout", "1.0.0", tmp_path.parent / "manifests", about=about()).path.with_suffix(".md").read_text()
    assert f"the trained planner nbvnet-3-3 epoch 0 (sha256 `{digest}`) chose" in card
    assert f"nbvdata generate --out {tmp_path.name} --policy CHECKPOINT" in card
    assert f"policy followed: nbvnet-3-3 epoch 0, checkpoint sha256 {digest}" in card


def test_a_bad_checkpoint_is_one_line_and_exit_2(tmp_path, capsys):
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    assert main(["generate", "--out", str(tmp_path / "out"), "--config", str(SMOKE), "--policy", str(junk)]) == 2
    err = capsys.readouterr().err.strip()
    assert "junk.pt: not a PyTorch checkpoint (a text file)" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists()  # refused before anything was written


PROVIDER = """
class FixedView:
    \"\"\"A policy of another package: always the candidate view its file names.\"\"\"

    def __init__(self, path, config, threads):
        self.view = int(path.read_text())
        self.name = f"fixed view {self.view}"

    def start(self, seed):
        pass

    def next_move(self, probabilities, poses):
        return self.view
"""


def test_any_package_can_provide_a_policy_through_the_entry_points(tmp_path, monkeypatch, mug, capsys):
    """nbvdata finds providers in the nbvdata.policies entry-point group only: nbvtrain's
    checkpoint provider is one (registered in pyproject.toml), another package's is another."""
    from importlib.metadata import EntryPoint

    import nbvdata.simulation.policy
    from nbvtrain.planners.provider import CheckpointPolicy

    assert nbvdata.simulation.policy.load_provider("checkpoint") is CheckpointPolicy  # the installed entry point
    (tmp_path / "other_package.py").write_text(PROVIDER)
    monkeypatch.syspath_prepend(str(tmp_path))
    installed = nbvdata.simulation.policy.entry_points
    fixed = EntryPoint(name="fixed", value="other_package:FixedView", group=nbvdata.simulation.policy.GROUP)
    monkeypatch.setattr(nbvdata.simulation.policy, "entry_points",
                        lambda group: [*installed(group=group), *([fixed] if group == nbvdata.simulation.policy.GROUP else [])])
    (tmp_path / "view.txt").write_text("5")
    source = PolicySource.from_path(tmp_path / "view.txt", provider="fixed")
    generate(mug, tmp_path / "out", _config("episode.runs_per_mesh=2"), show_progress=False, policy=source)
    arrays = _arrays(tmp_path / "out")
    followed = arrays["move"] == 2
    assert followed.any() and (arrays["next_view"][followed] == 5).all()
    digest = hashlib.sha256(b"5").hexdigest()
    assert arrays["policy"] == {"sha256": digest, "network": "fixed view 5", "provider": "fixed"}

    (tmp_path / "other.txt").write_text("7")
    argv = ["generate", "--out", str(tmp_path / "out"), "--config", str(SMOKE), "--runs-per-mesh", "2"]
    for extra, message in ((["--policy", str(tmp_path / "other.txt"), "--policy-provider", "fixed"],
                            "follow the policy fixed view 5 of provider fixed (sha256 "),
                           (["--policy", str(tmp_path / "view.txt"), "--policy-provider", "nope"],
                            "--policy-provider nope: no installed package registers the policy provider 'nope'; "
                            "installed providers: checkpoint, fixed"),
                           (["--policy-provider", "fixed"], "--policy-provider fixed: give the file it reads too")):
        assert main([*argv, *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err
    monkeypatch.setattr(nbvdata.simulation.policy, "entry_points", lambda group: [])  # a checkout never pip-installed
    with pytest.raises(nbvdata.simulation.policy.PolicyError, match="needs nbvtrain and PyTorch: no installed package registers "
                       "the 'checkpoint' policy provider"):
        nbvdata.simulation.policy.load_provider("checkpoint")


def test_without_torch_generate_runs_and_policy_names_the_install_command(tmp_path, checkpoints):
    code = ("import sys; sys.modules['torch'] = None\n"
            "from nbvdata.cli import main\n"
            f"assert main(['generate', '--out', {str(tmp_path / 'plain')!r}, '--config', {str(SMOKE)!r}, "
            "'--runs-per-mesh', '1', '--workers', '1', '--explore', '0.5', '--no-progress']) == 0\n"
            f"sys.exit(main(['generate', '--out', {str(tmp_path / 'policy')!r}, '--config', {str(SMOKE)!r}, "
            f"'--policy', {str(checkpoints['nbvnet-3-3'])!r}]))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))
    err = done.stderr.strip()
    assert done.returncode == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert "--policy needs nbvtrain and PyTorch" in err and 'pip install torch==2.13.0 -e ".[train]"' in err
