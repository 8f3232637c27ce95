"""What regression networks answer on a run's validation states, offline: how committed their
answers are and how good the candidate view nearest to each answer is, beside a random view.

For each checkpoint (regression networks trained on the same shards), on a seeded sample of the
validation states that ``RUN/data.json`` records (its shards and ``val_indices``):

- norm: the median length of the (3,) answer (tanh outputs; a unit target gives 1, the mean of
  two opposite good views 0),
- gain ratio: the mean over states of the gain of the candidate view nearest to the answer over
  the best eligible gain (0 for a view that breaks the overlap rule or was scanned:
  ``nbvtrain.networks.metrics.gain_ratio`` with the scanned views counted invalid),
- resultant: the length of the mean answer direction (1: one direction for every state; the
  labels' own is printed beside),
- views: how many candidate views the answers land on.

The random row is the mean gain ratio of a uniformly random unscanned view. The closed loop
(``nbvtrain evaluate``) decides; this says why it goes as it does. ``--shards DIR`` takes the
states of DIR instead of the run's validation states: e.g. a policy's own rollout on the validation
objects (``nbvdata generate --manifest M --part val --policy CKPT``), where a state reached through
a pose counts that scan as its nearest candidate view (``nbvtrain.networks.training_data.nearest_views``).

    python recipes/regression_answers.py RUN CKPT [CKPT...] [--samples 1500] [--seed 0] [--shards DIR]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from nbvdata.schema.shards import shard_files
from nbvtrain.networks.metrics import gain_ratio, nearest_view, unit
from nbvtrain.networks.predict import Predictor
from nbvtrain.networks.training_data import load_shards, load_view_states, to_grids


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a run folder of nbvtrain fit (its data.json)")
    parser.add_argument("checkpoints", type=Path, nargs="+", help="regression checkpoints to compare")
    parser.add_argument("--samples", type=int, default=1500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--shards", type=Path, help="states from these shards (a folder) instead of the run's "
                        "validation states")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    if args.shards is None:
        recorded = json.loads((args.run / "data.json").read_text())
        paths = [Path(p) for p in recorded["shards"]]
        source = f"validation states of {args.run}"
    else:
        paths = shard_files([args.shards])
        source = f"states of {args.shards}"
    data = load_shards(paths, grids=False)
    try:
        val = np.arange(len(data)) if args.shards is not None else np.array(recorded["val_indices"])
        chosen = np.sort(np.random.default_rng(args.seed).choice(val, min(args.samples, len(val)), replace=False))
        scanned = load_view_states(paths, poses="nearest")[chosen]
        eligible = data.valid[chosen] & ~scanned  # passes the overlap rule, not scanned
        gains = data.gains[chosen]
        codes = data.grids.take(chosen)
        palette = torch.from_numpy(data.palette)
        units = data.view_units
        labels = data.targets[chosen]
    finally:
        data.close()
    best = np.where(eligible, gains, 0.0).max(axis=1)
    ranked = best > 0
    print(f"{len(chosen)} {source} ({int(ranked.sum())} with a gain left)")
    print(f"{'answers':<50} {'norm':>6} {'gain ratio':>10} {'resultant':>9} {'views':>6}")

    def row(name: str, answers: np.ndarray) -> None:
        norms = np.linalg.norm(answers, axis=1)
        ratio = gain_ratio(answers, gains, eligible, units)[0].mean()
        resultant = np.linalg.norm(unit(answers).mean(axis=0))
        views = len(np.unique(nearest_view(answers, units)))
        print(f"{name:<50} {np.median(norms):6.2f} {ratio:10.3f} {resultant:9.2f} {views:6d}")

    for checkpoint in args.checkpoints:
        model = Predictor(checkpoint).model.eval()
        if model.task != "regression":
            raise SystemExit(f"{checkpoint}: a {model.task} network, not a regression one")
        with torch.inference_mode():
            answers = np.concatenate([model(to_grids(codes[i:i + 100], palette)).float().numpy()
                                      for i in range(0, len(codes), 100)])
        row(str(Path(*checkpoint.parts[-4:])), answers)
    row("labels", labels)
    relative = np.where(eligible, gains, 0.0)[ranked] / best[ranked, None]  # an ineligible view scores 0
    random = np.mean([ratios[~taken].mean() for ratios, taken in zip(relative, scanned[ranked])])
    print(f"{'random unscanned view':<50} {'-':>6} {random:10.3f} {'-':>9} {'-':>6}")


if __name__ == "__main__":
    main()
