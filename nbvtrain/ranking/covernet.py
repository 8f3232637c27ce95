"""SCVP's one-shot set-cover network (Pan, Hu, Wei, RA-L 2022), reproduced from their published
code's facts, trained on our exact cover labels: the 32^3 occupancy grid in, one probability per
candidate view of ``scvp-32`` out, a view in the predicted set when its probability is >= 0.5.

The network (their ``MyNBVNetV3``; ``width`` w = 32 is theirs):

- a stem: Conv3d(1 -> w, 3, padding 1, with bias; no normalisation, no activation), max-pool 2 (16^3);
- four residual blocks (their ``RVPBlock``) of w -> 2w -> 4w -> 8w -> 16w channels, each followed by
  a max-pool 2 (8^3, 4^3, 2^3, 1^3). A block is two halves of two [Conv3d 3x3x3 without bias,
  BatchNorm3d, ReLU]; the first half's output is added to the second's, then a ReLU;
- dense skips: after each block the pooled output is joined (channels) with the max-pooled join
  before it, so the 1^3 join holds w + 2w + 4w + 8w + 16w = 31 w channels (992);
- a head of Linear 31w -> 512 -> 256 -> 128 -> 64, each with ReLU and Dropout(0.5), then
  Linear 64 -> V and a sigmoid.

Their loss (``NBVLoss2`` in their training code): the squared error of every output against the
0/1 label, summed, positives weighted 2 and negatives 1 (``POSITIVE_WEIGHT``); Adam, learning rate
2e-4, batch 32, 300 epochs, no schedule. Their input is the grid alone (probabilities, 0.5 unknown)
and their labels are the covers of first-scan states; ours are every state of a run (the cover of
what it has left), so the network also plans again from later states (re-activation).

``fit_covernet`` trains it on shards holding covers (``nbvdata generate --set oracle.cover=true``)
of one view layout, validates on the mesh split's val meshes, and writes a checkpoint that loads
with ``weights_only=True`` (``load_covernet``).
"""

from __future__ import annotations

import csv
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from nbvdata.core.config import ConfigError
from nbvdata.schema.shards import Shard, ShardError, has_covers
from nbvtrain.networks.checkpoint import WEIGHTS_KEY, CheckpointError, check_weights, weights_digest

POSITIVE_WEIGHT = 2.0  # SCVP's weight of a label-1 output in the summed squared error (negatives: 1)
THRESHOLD = 0.5  # a view is in the predicted set when its probability reaches this (SCVP's)
FORMAT = "nbvtrain-covernet"
USE_FIT = "pass a checkpoint written by nbvtrain fit --model scvp-net (runs/NAME/covernet.pt)"


def network(views: int = 32, width: int = 32, dropout: float = 0.5):
    """SCVP's network (module docstring): (B, 1, 32, 32, 32) probabilities -> (B, views) probabilities."""
    import torch
    import torch.nn as nn

    def convs(inputs: int, outputs: int) -> nn.Sequential:
        return nn.Sequential(nn.Conv3d(inputs, outputs, 3, padding=1, bias=False), nn.BatchNorm3d(outputs),
                             nn.ReLU(inplace=True), nn.Conv3d(outputs, outputs, 3, padding=1, bias=False),
                             nn.BatchNorm3d(outputs), nn.ReLU(inplace=True))

    class Block(nn.Module):
        def __init__(self, inputs: int, outputs: int):
            super().__init__()
            self.first, self.second = convs(inputs, outputs), convs(outputs, outputs)

        def forward(self, x):
            x = self.first(x)
            return torch.relu(self.second(x) + x)

    class SCVPNet(nn.Module):
        def __init__(self):
            super().__init__()
            self.views, self.width = views, width
            self.stem = nn.Conv3d(1, width, 3, padding=1)
            self.blocks = nn.ModuleList(Block(width * 2 ** k, width * 2 ** (k + 1)) for k in range(4))
            self.pool = nn.MaxPool3d(2)
            layers, size = [], 31 * width
            for hidden in (512, 256, 128, 64):
                layers += [nn.Linear(size, hidden), nn.ReLU(inplace=True), nn.Dropout(dropout)]
                size = hidden
            self.head = nn.Sequential(*layers, nn.Linear(size, views))

        def forward(self, grids):
            x = self.pool(self.stem(grids))
            joined = x
            for block in self.blocks:
                x = self.pool(block(x))
                joined = torch.cat([x, self.pool(joined)], dim=1)
            return torch.sigmoid(self.head(joined.flatten(1)))

    return SCVPNet()


def scvp_loss(probabilities, labels):
    """SCVP's loss: sum of (p - y)^2, label-1 outputs weighted ``POSITIVE_WEIGHT`` (module docstring)."""
    weights = 1.0 + (POSITIVE_WEIGHT - 1.0) * labels
    return (weights * (probabilities - labels) ** 2).sum()


@dataclass(frozen=True)
class CoverNetConfig:
    """How ``scvp-net`` is trained (their settings, but the epochs and the width, which a CPU cannot
    afford at theirs: 300 epochs of w = 32)."""

    width: int = 32
    """Channels of the stem (SCVP: 32); the blocks double it."""
    epochs: int = 300
    """Passes over the training states (SCVP: 300)."""
    batch: int = 32
    """States per batch (SCVP: 32)."""
    learning_rate: float = 2e-4
    """Adam's step (SCVP: 2e-4)."""
    train_states: int = 0
    """Use at most this many training states (a seeded choice; 0: all)."""
    seed: int = 0
    threads: int = 2

    def __post_init__(self) -> None:
        if self.width < 1 or self.epochs < 1 or self.batch < 1 or not self.learning_rate > 0 or self.train_states < 0:
            raise ConfigError("scvp-net: width, epochs and batch must be >= 1, lr > 0, train states >= 0")


def cover_states(parts, what: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """(grids (N, 32, 32, 32) float32 probabilities, covers (N, V) bool, steps (N,) int32, scene) of
    ``parts`` (``nbvtrain.ranking.rankfit.Part``: shard path and states); ShardError for a shard without covers
    or of another view set than the first."""
    grids, covers, steps, views = [], [], [], None
    for part in parts:
        with Shard(part.path) as shard:
            if not has_covers(shard.info.config or {}):
                raise ShardError(f"{part.path}: no set-cover labels; generate with --set oracle.cover=true")
            positions = shard["view_positions"]
            if views is None:
                views = positions
            elif positions.shape != views.shape or not np.allclose(positions, views):
                raise ShardError(f"{part.path}: other candidate views than {parts[0].path}: scvp-net predicts one "
                                 "view set; give shards of one layout")
            grids.append(shard.grids(part.states))
            covers.append(shard.read("cover", part.states).astype(bool))
            steps.append(shard.read("step", part.states).astype(np.int32))
    if views is None:
        raise ShardError(f"no {what} states")
    return (np.concatenate(grids).astype(np.float32), np.concatenate(covers), np.concatenate(steps),
            {"view_positions": views})


def set_quality(probabilities: np.ndarray, covers: np.ndarray) -> dict:
    """``nbvtrain.ranking.covermodel.set_quality`` of SCVP's sets (the views of probability >= ``THRESHOLD``)
    against ``covers``, both (N, V) over every candidate view of each state."""
    from nbvtrain.ranking.covermodel import set_quality as quality

    count, views = covers.shape
    return quality((probabilities >= THRESHOLD).ravel(), covers.ravel(), np.full(count, views),
                   covers.sum(axis=1))


def fit_covernet(items: list[Path], config: CoverNetConfig, out: Path, root: Path | None = None,
                 progress: bool = False) -> dict:
    """Train ``scvp-net`` on the covers of ``items`` (manifests or shard folders of one layout; the
    split of ``nbvtrain.ranking.rankdata.sources_parts``) into ``out``: ``covernet.pt`` (the epoch with the
    lowest validation loss), ``metrics.json``, ``history.csv``; returns the metrics."""
    import torch
    from tqdm import tqdm

    from nbvtrain.ranking.rankdata import finite, sources_parts

    started = time.perf_counter()
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    train_parts, val_parts, records = sources_parts(items, root, seed=config.seed)
    grids, covers, _, scene = cover_states(train_parts, "training")
    val_grids, val_covers, val_steps, _ = cover_states(val_parts, "validation")
    rng = np.random.default_rng(config.seed)
    if config.train_states and config.train_states < len(grids):
        chosen = np.sort(rng.choice(len(grids), config.train_states, replace=False))
        grids, covers = grids[chosen], covers[chosen]
    views = covers.shape[1]
    model = network(views, config.width)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    x, y = torch.from_numpy(grids)[:, None], torch.from_numpy(covers.astype(np.float32))
    val_x, val_y = torch.from_numpy(val_grids)[:, None], torch.from_numpy(val_covers.astype(np.float32))
    out.mkdir(parents=True, exist_ok=True)
    history, best, best_state = [], float("inf"), None
    for epoch in range(1, config.epochs + 1):
        model.train()
        total = 0.0
        order = rng.permutation(len(x))
        for batch in tqdm(np.array_split(order, max(1, len(order) // config.batch)), desc=f"scvp-net epoch {epoch}",
                          disable=not progress, dynamic_ncols=True):
            loss = scvp_loss(model(x[batch]), y[batch])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += float(loss.detach())
        probabilities = predict_probabilities(model, val_x)
        val_loss = float(scvp_loss(torch.from_numpy(probabilities), val_y)) / len(val_x)
        quality = set_quality(probabilities, val_covers)
        history.append({"epoch": epoch, "train_loss": total / len(x), "val_loss": val_loss} | quality)
        if val_loss < best:
            best = val_loss
            best_state = {key: value.detach().clone() for key, value in model.state_dict().items()}
    model.load_state_dict(best_state)
    save_covernet(out / "covernet.pt", model, config, scene, records)
    probabilities = predict_probabilities(model, val_x)
    metrics = {"model": "scvp-net", "file": "covernet.pt", "config": asdict(config),
               "train_states": len(x), "val_states": len(val_x), "best_val_loss": best,
               "val": set_quality(probabilities, val_covers),
               "val_by_step": {int(step): set_quality(probabilities[val_steps == step], val_covers[val_steps == step])
                               for step in np.unique(val_steps)[:10]},
               "seconds": round(time.perf_counter() - started, 1), "sources": records}
    (out / "metrics.json").write_text(json.dumps(finite(metrics), indent=1, allow_nan=False) + "\n")
    with (out / "history.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(history[0]))
        writer.writeheader()
        writer.writerows(history)
    return metrics


def predict_probabilities(model, grids, batch: int = 64) -> np.ndarray:
    """(N, V) float32 the network's probabilities for (N, 1, n, n, n) grids (a tensor), in eval mode."""
    import torch

    model.eval()
    with torch.no_grad():
        return np.concatenate([model(grids[k:k + batch]).numpy() for k in range(0, len(grids), batch)]) \
            if len(grids) else np.zeros((0, model.views), dtype=np.float32)


def save_covernet(path: Path, model, config: CoverNetConfig, scene: dict, sources: list) -> None:
    """Write the checkpoint: tensors and plain values only (``weights_only=True`` reads it)."""
    import torch

    state = {"format": FORMAT, "views": int(model.views), "width": int(model.width),
             "view_positions": torch.from_numpy(np.asarray(scene["view_positions"], dtype=np.float64)),
             "state_dict": {key: value.detach().clone() for key, value in model.state_dict().items()},
             "training": json.loads(json.dumps({"config": asdict(config), "sources": sources}, allow_nan=False))}
    state[WEIGHTS_KEY] = weights_digest(state["state_dict"])
    partial = path.with_name(path.name + ".partial")
    torch.save(state, partial)
    partial.replace(path)


class CoverNet:
    """A trained ``scvp-net``: ``probabilities(grid) -> (V,)`` over its ``view_positions`` (V, 3)."""

    def __init__(self, model, view_positions: np.ndarray, path: Path):
        self.model, self.view_positions, self.path = model, view_positions, path

    def probabilities(self, grid: np.ndarray) -> np.ndarray:
        import torch

        x = torch.from_numpy(np.asarray(grid, dtype=np.float32))[None, None]
        return predict_probabilities(self.model, x)[0].astype(np.float64)


def load_covernet(path: str | Path) -> CoverNet:
    """The ``scvp-net`` checkpoint in ``path``; CheckpointError naming the file and the fix for
    anything else (read with ``weights_only=True``: nothing is unpickled)."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint; {USE_FIT}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # any foreign file: say what it is not
        raise CheckpointError(f"{path}: not a scvp-net checkpoint ({type(error).__name__}); {USE_FIT}") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a scvp-net checkpoint (no format {FORMAT!r}); {USE_FIT}")
    check_weights(state, path, USE_FIT)
    try:
        model = network(int(state["views"]), int(state["width"]))
        model.load_state_dict(state["state_dict"])
    except (KeyError, RuntimeError, TypeError) as error:
        raise CheckpointError(f"{path}: its weights do not fit scvp-net ({type(error).__name__}); {USE_FIT}") from None
    model.eval()
    return CoverNet(model, state["view_positions"].numpy(), path)
