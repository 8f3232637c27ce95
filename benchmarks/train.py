"""Training throughput on this machine, what CPU speed-ups buy, and whether the loader keeps up.

For each model: samples/s of training steps (forward, backward, Adam) beside the time the
loader needs to assemble the same batches (gather codes, quarter-turn augmentation, palette
lookup; it runs in a thread ahead of the model during fit). Each model is also timed with the
CPU speed-ups one could switch on, in the same process against its plain float32 steps:
bfloat16 autocast (oneDNN's AVX-512 BF16 kernels where the CPU has them) and channels-last
3D memory. A score network (nbvscore-*) is timed with its own loss on the shards' gains.

    python benchmarks/train.py SHARDS_OR_FOLDERS... [--models nbvnet-4-3,nbvscore-3] [--batches 4]
"""

from __future__ import annotations

import argparse
import contextlib
import time
from pathlib import Path

import numpy as np
import torch

from nbvdata.schema.shards import shard_files
from nbvtrain.networks.models import MODELS, build_model
from nbvtrain.networks.scores import score_loss
from nbvtrain.networks.training_data import load_shards, load_view_states, rotate_quarter_turns, to_grids

VARIANTS = ("float32", "bf16 autocast", "channels-last")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shards", type=Path, nargs="+")
    parser.add_argument("--models", default=",".join(MODELS))
    parser.add_argument("--batch-size", type=int, default=250, help="NBV-nets' batch (score networks: 64)")
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
    names = args.models.split(",")
    taken = load_view_states(data.paths) if any(MODELS[n].task == "scores" for n in names) else None

    batches = [rng.choice(len(data), args.batch_size) for _ in range(args.batches)]
    started = time.perf_counter()
    for index in batches:
        codes, targets = rotate_quarter_turns(data.grids.take(index), data.targets[index],
                                              rng.integers(0, 4, len(index)))
        to_grids(codes, palette)
    loader = (time.perf_counter() - started) / len(batches)
    print(f"loader: {1e3 * loader:.0f} ms per batch of {args.batch_size} ({args.batch_size / loader:.0f} samples/s)")
    print(f"{'model':14s} {'variant':14s} {'batch':>5s} {'ms/batch':>9s} {'samples/s':>9s} {'x float32':>9s} "
          f"{'loader share':>12s}")
    for name in names:
        size = 64 if MODELS[name].task == "scores" else args.batch_size
        chosen = [rng.choice(len(data), size) for _ in range(args.batches + 1)]
        baseline = None
        for variant in VARIANTS:
            per_batch = _time_steps(name, variant, data, taken, chosen, palette)
            baseline = baseline or per_batch
            print(f"{name:14s} {variant:14s} {size:5d} {1e3 * per_batch:9.0f} {size / per_batch:9.0f} "
                  f"{baseline / per_batch:8.2f}x {loader * size / args.batch_size / per_batch:11.1%}")


def _time_steps(name: str, variant: str, data, taken, batches: list[np.ndarray], palette: torch.Tensor) -> float:
    """Median seconds of one training step of ``name`` under ``variant`` (the first step warms up)."""
    torch.manual_seed(0)
    model = build_model(name, views=data.view_units).train()
    memory = torch.channels_last_3d if variant == "channels-last" else torch.contiguous_format
    model = model.to(memory_format=memory)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)
    autocast = (torch.autocast("cpu", dtype=torch.bfloat16) if variant == "bf16 autocast"
                else contextlib.nullcontext())
    times = []
    for step, index in enumerate(batches):
        grids = to_grids(data.grids.take(index), palette).contiguous(memory_format=memory)
        started = time.perf_counter()
        with autocast:
            if model.task == "scores":
                scanned = torch.from_numpy(taken[index])
                loss = score_loss(model(grids, scanned), torch.from_numpy(data.gains[index]),
                                  torch.from_numpy(data.valid[index]), scanned)
            else:
                output = model(grids)
                target = (torch.from_numpy(data.targets[index]) if model.task == "regression"
                          else torch.zeros(len(index), dtype=torch.long))
                loss = (torch.nn.functional.mse_loss(output.float(), target) if model.task == "regression"
                        else torch.nn.functional.cross_entropy(output.float(), target))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if step:
            times.append(time.perf_counter() - started)
    return float(np.median(times))


if __name__ == "__main__":
    main()
