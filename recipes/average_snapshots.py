"""Average the weights of several snapshots of one run into one checkpoint (issue 27's idea:
snapshot averaging of the regression network, measured on the validation objects).

    python recipes/average_snapshots.py OUT.pt runs/selection/fit/regression-dagger/snapshots/epoch-00{3,4,5}.pt

The checkpoint is the last snapshot's with each weight the mean of the snapshots' (in float64,
stored in the weight's own dtype) and no optimizer state: ``nbvtrain evaluate --checkpoint OUT.pt``
reads it. Only for networks without batch normalisation (the averaged running statistics
would not be the averaged network's); the snapshots must be of the same model.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nbvtrain.networks.checkpoint import load_checkpoint, save_checkpoint


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("snapshots", nargs="+", type=Path)
    args = parser.parse_args()
    states = [load_checkpoint(path) for path in args.snapshots]
    last = states[-1]
    if any(state["model"] != last["model"] for state in states):
        raise SystemExit(f"snapshots of different models: {sorted({state['model'] for state in states})}")
    if any("running_mean" in key for key in last["state_dict"]):
        raise SystemExit(f"{last['model']} has batch normalisation: averaging its weights is not this script's job")
    averaged = {key: sum(state["state_dict"][key].double() for state in states).div(len(states)).to(tensor.dtype)
                for key, tensor in last["state_dict"].items()}
    save_checkpoint(args.out, {**{k: v for k, v in last.items() if k != "optimizer"}, "state_dict": averaged})
    print(f"{args.out}: the mean of {len(states)} snapshots of {last['model']}")


if __name__ == "__main__":
    main()
