"""Training throughput on this machine, and whether the data loader keeps up with the model.

For each model: samples/s of training steps (forward, backward, Adam) at the paper's batch
size, beside the time the loader needs to assemble the same batches (gather codes, quarter-turn
augmentation, palette lookup). The loader runs in a thread ahead of the model during fit, so
it is hidden when its time per batch is well below the step's.

    python benchmarks/train.py SHARDS_OR_FOLDERS... [--models nbvnet-4-5,nbvnet-3-3] [--batches 4]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from nbvdata.shards import shard_files
from nbvtrain.data import load_shards, rotate_quarter_turns, to_grids
from nbvtrain.models import MODELS, build_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shards", type=Path, nargs="+")
    parser.add_argument("--models", default=",".join(m for m in MODELS))
    parser.add_argument("--batch-size", type=int, default=250)
    parser.add_argument("--batches", type=int, default=4)
    args = parser.parse_args()

    started = time.perf_counter()
    data = load_shards(shard_files(args.shards))
    seconds = time.perf_counter() - started
    print(f"loaded {len(data)} samples into memory in {seconds:.1f} s ({len(data) / seconds:.0f} samples/s), "
          f"{data.grids.codes.nbytes / 2 ** 20:.0f} MiB of grid codes; torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads")
    rng = np.random.default_rng(0)
    palette = torch.from_numpy(data.palette)
    batches = [rng.choice(len(data), args.batch_size) for _ in range(args.batches)]

    started = time.perf_counter()
    for index in batches:
        codes, targets = rotate_quarter_turns(data.grids.take(index), data.targets[index],
                                              rng.integers(0, 4, len(index)))
        to_grids(codes, palette)
    loader = (time.perf_counter() - started) / len(batches)
    print(f"loader: {1e3 * loader:.0f} ms per batch of {args.batch_size} ({args.batch_size / loader:.0f} samples/s)")
    print(f"{'model':14s} {'ms/batch':>9s} {'samples/s':>9s} {'loader share':>12s}")
    for name in args.models.split(","):
        torch.manual_seed(0)
        model = build_model(name).train()
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)
        loss_fn = torch.nn.MSELoss() if model.task == "regression" else torch.nn.CrossEntropyLoss()
        times = []
        for step, index in enumerate([batches[0]] + batches):
            grids = to_grids(data.grids.take(index), palette)
            target = torch.from_numpy(data.targets[index])
            if model.task == "classification":
                target = torch.zeros(len(index), dtype=torch.long)
            started = time.perf_counter()
            loss = loss_fn(model(grids), target)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            if step:  # the first step warms up
                times.append(time.perf_counter() - started)
        per_batch = float(np.median(times))
        print(f"{name:14s} {1e3 * per_batch:9.0f} {args.batch_size / per_batch:9.0f} {loader / per_batch:11.1%}")


if __name__ == "__main__":
    main()
