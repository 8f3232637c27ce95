"""The dataset in anyone's training code: a ``torch.utils.data.Dataset`` over shards or a
published version, for a plain ``DataLoader`` with worker processes.

Each item is a dict (the default collate stacks them into a batch)::

    grid      (1, n, n, n) float32   occupancy probabilities, 0.5 = unknown (object frame, [x, y, z])
    target    (3,) float32           the unit NBV position, what ``nbvtrain fit`` regresses
    index     int                    the sample's global index (shard order, rows in order)
    gains     (V,) float32           with scores=True: every candidate view's gain (``nbvdata.simulation.oracle``)
    overlaps  (V,) float32           with scores=True: every candidate view's overlap
    taken     (V,) bool              with view_state=True: the candidate views scanned so far
    points    (P, 3) float32         with points=True: the state's partial cloud, object frame, metres
                                     (shards made with state.points = P; ``nbvdata.core.cloud``)
    points_count int                 with points=True: how many points were scanned (<= P: the first
                                     points_count rows are all of them)

Samples are read exactly as ``nbvtrain fit`` reads them (``nbvtrain.networks.training_data.load_shards``: one
merged palette, the same global indices, a published version's split parts), so a model trained
here sees the data fit would. Grids are held in memory as palette codes while they fit in
``memory_limit_gb`` (worker processes share them), else each worker process opens the shards
itself and reads its samples lazily.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from nbvdata.schema.manifest import Published, open_verified
from nbvdata.schema.shards import Shard, ShardError, shard_files
from nbvtrain.networks.training_data import (LazyClouds, LazyGrids,  # noqa: F401 (view_state: public here too)
                                             load_shards, load_view_states, view_state)


class NBVDataset(torch.utils.data.Dataset):
    """The samples of shards (files or folders) or of a published manifest (NAME-X.Y.Z.json).

    With a manifest, ``part`` ("train", "val", "test"; None = every sample) of its ``split``
    ("random" or "mesh") selects the samples, as ``nbvtrain fit MANIFEST --split ...`` trains and
    validates on them; its shards are verified first (under ``root``, default the recorded one).
    Shards made in different scenes are refused unless ``mixed_scenes`` (as ``nbvtrain fit``).
    """

    def __init__(self, source: str | Path | Sequence[str | Path], part: str | None = None, split: str = "random",
                 root: str | Path | None = None, scores: bool = False, view_state: bool = False,
                 memory_limit_gb: float = 8.0, mixed_scenes: bool = False, points: bool = False):
        sources = [Path(source)] if isinstance(source, (str, Path)) else [Path(s) for s in source]
        published: Published | None = None
        if len(sources) == 1 and sources[0].suffix == ".json":
            published = open_verified(sources[0], root)
            paths = published.shard_paths
        else:
            if part is not None:
                raise ShardError(f"part={part!r} needs a published manifest (NAME-X.Y.Z.json); on shards, take "
                                 "indices from nbvtrain.networks.training_data.split_indices and wrap in torch.utils.data.Subset")
            paths = shard_files(sources)
        data = load_shards(paths, memory_limit_gb, mixed_scenes, clouds="NBVDataset(points=True)" if points else None)
        self.paths, self.palette, self.targets = list(paths), data.palette, data.targets
        if part is None:
            self.indices = np.arange(len(data))
        else:
            parts = published.split(split)
            if part not in parts:
                raise ShardError(f"part={part!r}: {published.label}'s {split} split has {', '.join(parts)}")
            self.indices = parts[part]
        self.gains = self.overlaps = self.taken = self.points_count = None
        self._clouds = None
        if points:
            self.points_count = self._column("points_count", np.int64, "points")
            self._clouds = data.clouds
            if isinstance(data.clouds, LazyClouds):  # each worker process opens its own
                self._clouds = ([shard.path for shard in data.clouds.shards], data.clouds.offsets, data.clouds.size)
                data.clouds.close()
        if scores:
            if data.gains is None:
                raise ShardError("scores=True: these shards do not all hold gains for one common set of views "
                                 "(imported data has none): use scores=False")
            self.gains, self.overlaps = data.gains, self._column("overlaps", np.float32, "scores")
        if view_state:
            self.taken = load_view_states(self.paths)
        self._grids = data.grids
        self._lazy = None
        if isinstance(data.grids, LazyGrids):  # h5py handles do not cross processes: each opens its own
            self._lazy = ([shard.path for shard in data.grids.shards], data.grids.offsets, data.grids.luts,
                          data.grids.dtype)
            data.grids.close()
            self._grids, self._pid = None, None

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, item: int) -> dict:
        index = int(self.indices[item])
        codes = self._grid_source().take(np.array([index]))[0]
        sample = {"grid": torch.from_numpy(self.palette[codes]).unsqueeze(0),
                  "target": torch.from_numpy(self.targets[index].copy()), "index": index}
        if self.gains is not None:
            sample["gains"] = torch.from_numpy(self.gains[index].copy())
            sample["overlaps"] = torch.from_numpy(self.overlaps[index].copy())
        if self.taken is not None:
            sample["taken"] = torch.from_numpy(self.taken[index].copy())
        if self.points_count is not None:
            sample["points"] = torch.from_numpy(self._cloud_source().take(np.array([index]))[0])
            sample["points_count"] = int(self.points_count[index])
        return sample

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        if self._lazy is not None:
            state["_grids"], state["_pid"] = None, None
        if isinstance(self._clouds, LazyClouds):
            state["_clouds"] = ([shard.path for shard in self._clouds.shards], self._clouds.offsets, self._clouds.size)
        return state

    def _cloud_source(self):
        if isinstance(self._clouds, tuple):  # a lazy dataset's clouds, opened in this process
            self._clouds = LazyClouds(*self._clouds)
        return self._clouds

    def close(self) -> None:
        """Close the shards a lazy dataset opened in this process."""
        if isinstance(self._clouds, LazyClouds):
            self._clouds.close()
        if self._grids is not None:
            self._grids.close()
            if self._lazy is not None:
                self._grids = None

    def _grid_source(self):
        if self._lazy is not None and (self._grids is None or self._pid != os.getpid()):
            self._grids, self._pid = LazyGrids(*self._lazy), os.getpid()
        return self._grids

    def _column(self, name: str, dtype: type, wanted: str) -> np.ndarray:
        """One per-sample dataset of every shard, concatenated in sample order."""
        columns = []
        for path in self.paths:
            with Shard(path) as shard:
                if not shard.has(name):
                    raise ShardError(f"{path}: no {name} (imported data): use {wanted}=False")
                columns.append(shard[name].astype(dtype))
        return np.concatenate(columns)
