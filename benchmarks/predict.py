"""Latency of one NBV prediction on this CPU: nbvnet-4-5, batch 1, grid in -> pose out.

Target (issue 4): <= 5 ms per NBV including the pose. Prints the median over repeated calls of
``Predictor.predict`` (oneDNN inference path + look-at pose) beside the plain eager model on
the same grids, in the same process, and checks both give the same direction.

    python benchmarks/predict.py [--model nbvnet-4-5] [--repeats 200] [--threads 2]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from nbvdata.core.views import Pose
from nbvtrain.networks.config import TrainConfig
from nbvtrain.networks.models import MODELS, build_model
from nbvtrain.networks.predict import Predictor
from nbvtrain.networks.train import save_training_state


def median_ms(call, grids: np.ndarray, repeats: int) -> float:
    for grid in grids[:10]:
        call(grid)
    times = []
    for i in range(repeats):
        started = time.perf_counter()
        call(grids[i % len(grids)])
        times.append(time.perf_counter() - started)
    return 1e3 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="nbvnet-4-5", choices=list(MODELS))
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    model = build_model(args.model).eval()
    rng = np.random.default_rng(0)
    grids = rng.choice(np.array([0.5, 0.4, 0.7, 0.12], dtype=np.float32), size=(32, 32, 32, 32))

    with tempfile.TemporaryDirectory() as tmp:
        checkpoint = Path(tmp) / "model.pt"
        save_training_state(checkpoint, model, torch.optim.Adam(model.parameters()), TrainConfig(model=args.model), [], 0, 0.4)
        predictor = Predictor(checkpoint)

    def eager(grid: np.ndarray) -> Pose:
        with torch.inference_mode():
            raw = model(torch.from_numpy(grid)[None, None]).numpy()[0].astype(np.float64)
        return Pose.look_at(raw / np.linalg.norm(raw) * 0.4)

    fast = median_ms(lambda grid: predictor.predict(grid)[0].pose, grids, args.repeats)
    plain = median_ms(eager, grids, args.repeats)
    same = all(np.allclose(predictor.predict(g)[0].pose.position, eager(g).position, atol=1e-6) for g in grids)
    print(f"{args.model}, batch 1, {torch.get_num_threads()} threads, grid -> pose, median of {args.repeats}:")
    print(f"  Predictor.predict (oneDNN path) {fast:6.2f} ms   target <= 5 ms: {'met' if fast <= 5 else 'NOT met'}")
    print(f"  eager model + look-at pose      {plain:6.2f} ms   ratio {plain / fast:.2f}x; same poses: {same}")


if __name__ == "__main__":
    main()
