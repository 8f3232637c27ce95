"""Training data from nbvdata shards: labels in memory, grids in memory or read lazily.

Reads shards only through ``nbvdata.schema.shards``. All shards' grid palettes are merged into one
(``ShardSet.palette``), so a batch of grids is one array of codes (B, n, n, n) that becomes
float32 probabilities by one table lookup, on the training device.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from nbvdata.core.text import plural
from nbvdata.schema.manifest import Published, mesh_split, random_split
from nbvdata.schema.shards import Shard, ShardError, view_state  # noqa: F401 (view_state: public here too)
from nbvtrain.networks.metrics import nearest_view
from nbvtrain.networks.trained_scene import mixed_scene_record, scene_difference, scene_record_of

__all__ = ["InMemoryGrids", "InMemoryClouds", "LazyClouds", "LazyGrids", "ShardSet", "load_clouds", "load_shards",
           "load_view_states", "nearest_views", "split_indices", "published_split", "rotate_quarter_turns",
           "to_grids", "view_state"]


class InMemoryGrids:
    """(N, n, n, n) codes held in one array."""

    def __init__(self, codes: np.ndarray):
        self.codes = codes

    def take(self, indices: np.ndarray) -> np.ndarray:
        """(B,) sample indices -> (B, n, n, n) codes."""
        return self.codes[indices]

    def close(self) -> None:
        pass


class InMemoryClouds:
    """(N, P, 3) float32 partial clouds held in one array."""

    def __init__(self, points: np.ndarray):
        self.points = points
        self.size = points.shape[1]  # points per cloud

    def take(self, indices: np.ndarray) -> np.ndarray:
        """(B,) sample indices -> (B, P, 3) float32 points."""
        return self.points[indices]

    def close(self) -> None:
        pass


class LazyClouds:
    """Clouds read from the shards at each request (for datasets larger than memory)."""

    def __init__(self, paths: list[Path], offsets: np.ndarray, size: int):
        self.shards = [Shard(path) for path in paths]
        self.offsets, self.size = offsets, size  # size: points per cloud

    def take(self, indices: np.ndarray) -> np.ndarray:
        indices = np.asarray(indices)
        out = np.empty((len(indices), self.size, 3), dtype=np.float32)
        which = np.searchsorted(self.offsets, indices, side="right") - 1
        for s in np.unique(which):
            mine = np.flatnonzero(which == s)
            rows = indices[mine] - self.offsets[s]
            unique_rows, inverse = np.unique(rows, return_inverse=True)  # h5py wants increasing rows
            out[mine] = self.shards[s].read("points", unique_rows)[inverse]
        return out

    def close(self) -> None:
        for shard in self.shards:
            shard.close()


def load_clouds(paths: list[Path], model: str, memory_limit_gb: float = 8.0) -> InMemoryClouds | LazyClouds:
    """The partial clouds (``points``) of every sample of ``paths``, in memory when they take at
    most ``memory_limit_gb``; ShardError naming the shard when one holds none (a point network
    ``model`` reads them) or the shards' clouds differ in size."""
    counts, sizes = [], set()
    for path in paths:
        with Shard(path) as shard:
            if not shard.has("points"):
                raise ShardError(f"{path}: holds no point clouds, which {model} reads: generate the shards with "
                                 "--set state.points=1024 (or train a grid network)")
            counts.append(len(shard))
            sizes.add(shard.file["points"].shape[1])
    if len(sizes) > 1:
        raise ShardError(f"the shards hold clouds of different sizes {sorted(sizes)}: train on one kind at a time")
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    size = sizes.pop()
    if sum(counts) * size * 12 > memory_limit_gb * 2 ** 30:
        return LazyClouds(list(paths), offsets, size)
    parts = []
    for path in paths:
        with Shard(path) as shard:
            parts.append(shard["points"])
    return InMemoryClouds(np.concatenate(parts))


class LazyGrids:
    """Codes read from the shards at each request (for datasets larger than memory)."""

    def __init__(self, paths: list[Path], offsets: np.ndarray, luts: list[np.ndarray], dtype: np.dtype):
        self.shards = [Shard(path) for path in paths]
        self.offsets, self.luts, self.dtype = offsets, luts, dtype

    def take(self, indices: np.ndarray) -> np.ndarray:
        indices = np.asarray(indices)
        n = self.shards[0].file["grids"].shape[1]
        out = np.empty((len(indices), n, n, n), dtype=self.dtype)
        which = np.searchsorted(self.offsets, indices, side="right") - 1
        for s in np.unique(which):
            mine = np.flatnonzero(which == s)
            rows = indices[mine] - self.offsets[s]
            order = np.argsort(rows)
            unique_rows, inverse = np.unique(rows[order], return_inverse=True)
            block = self.shards[s].codes(unique_rows)  # h5py wants increasing rows
            out[mine[order]] = self.luts[s][block[inverse]]
        return out

    def close(self) -> None:
        for shard in self.shards:
            shard.close()


@dataclass
class ShardSet:
    """Every sample of some shards, in the order given (N samples, V candidate views).

    targets      : (N, 3) float32 unit NBV positions (the regression target)
    palette      : (K,) float32 probability of each grid code
    mesh_ids     : (N,) str, or None when a shard has no mesh ids (imported data)
    gains        : (N, V) float32 gain of every candidate view, or None when not every shard
                   has them for one common view set
    valid        : (N, V) bool, each view's overlap >= its shard's ``oracle.min_overlap`` (None with gains)
    view_units   : (V, 3) float64 unit candidate positions (None with gains)
    view_radius  : metres from the object centre to the views
    scene        : the grid and view settings the shards were made with (``nbvtrain.networks.trained_scene.scene_record``),
                   None when a shard records none (imported data), ``mixed_scene_record`` when they
                   were made in several scenes (``load_shards(mixed_scenes=True)``)
    clouds       : the partial clouds (``load_clouds``: ``take(indices)`` -> (B, P, 3)), or None when
                   not asked for
    """

    paths: list[Path]
    grids: InMemoryGrids | LazyGrids
    palette: np.ndarray
    targets: np.ndarray
    mesh_ids: np.ndarray | None
    gains: np.ndarray | None
    valid: np.ndarray | None
    view_units: np.ndarray | None
    view_radius: float
    grid_size: int
    scene: dict | None = None
    clouds: InMemoryClouds | LazyClouds | None = None

    def __len__(self) -> int:
        return len(self.targets)

    @property
    def cloud_points(self) -> int | None:
        """Points per cloud (the shards' ``state.points``), None without clouds."""
        return None if self.clouds is None else int(self.clouds.size)

    def close(self) -> None:
        self.grids.close()
        if self.clouds is not None:
            self.clouds.close()


def load_shards(paths: list[Path], memory_limit_gb: float = 8.0, mixed_scenes: bool = False,
                clouds: str | None = None, grids: bool = True) -> ShardSet:
    """Open ``paths`` (shard files) as one ``ShardSet``; raises ShardError naming a bad shard, or
    two shards made in different scenes (``nbvtrain.networks.trained_scene.scene_difference``) unless
    ``mixed_scenes``.

    ``clouds``: what reads the shards' partial clouds (a point network's name, for messages): they
    are loaded too (``load_clouds``). ``grids`` False: the grids are not wanted, left on disk
    (read lazily if at all)."""
    if not paths:
        raise ShardError("no shards given: pass .h5 files or folders written by nbvdata generate")
    infos = []
    for path in paths:
        with Shard(path) as shard:
            f = shard.file
            infos.append({
                "samples": len(shard), "palette": shard.palette, "size": f["grids"].shape[1:],
                "dtype": f["grids"].dtype, "targets": shard["nbv_position"].astype(np.float32),
                "mesh_id": shard["mesh_id"].astype(str) if shard.has("mesh_id") else None,
                "gains": shard["gains"] if shard.has("gains") else None,
                "valid": _valid_views(shard),
                "views": shard["view_positions"],
                "settings": shard.info.config, "scene": scene_record_of(shard.info.config),
            })
    scenes_differ = False
    for path, info in zip(paths[1:], infos[1:]):
        difference = scene_difference(infos[0]["settings"], info["settings"])
        if difference is not None and not mixed_scenes:
            key, first, other = difference
            raise ShardError(f"{path} was made in another scene than {paths[0]} ({key} {other!r}, not {first!r}): "
                             "train on the shards of one scene, or pass --mixed-scenes (mixed_scenes=True) to mix "
                             "them knowingly")
        scenes_differ |= difference is not None
    sizes = {info["size"] for info in infos if info["samples"]}
    if len(sizes) > 1:
        raise ShardError(f"the shards hold grids of different sizes {sorted(sizes)}: train on one kind at a time")
    size = (sizes or {(32, 32, 32)}).pop()[0]
    palette = np.unique(np.concatenate([info["palette"] for info in infos]).astype(np.float32))
    luts = [np.searchsorted(palette, info["palette"]) for info in infos]
    code_type = np.uint8 if len(palette) <= 256 else np.uint16
    luts = [lut.astype(code_type) for lut in luts]
    counts = np.array([info["samples"] for info in infos])
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    total = int(counts.sum())
    if total == 0:
        raise ShardError(f"no samples in the {plural(len(paths), 'shard')} given: generate more runs or other meshes")

    cloud_source = None if clouds is None else load_clouds(paths, clouds, memory_limit_gb)
    nbytes = total * size ** 3 * np.dtype(code_type).itemsize
    if grids and nbytes <= memory_limit_gb * 2 ** 30:
        codes = np.empty((total, size, size, size), dtype=code_type)
        for path, lut, start, count in zip(paths, luts, offsets, counts):
            if count:
                with Shard(path) as shard:
                    codes[start:start + count] = lut[shard.codes()]
        grid_source: InMemoryGrids | LazyGrids = InMemoryGrids(codes)
    else:
        grid_source = LazyGrids(list(paths), offsets, luts, np.dtype(code_type))

    views = infos[0]["views"]
    radius = float(np.linalg.norm(views, axis=1).mean())
    same_views = all(info["views"].shape == views.shape and np.allclose(info["views"], views) for info in infos)
    has_gains = same_views and all(info["gains"] is not None and info["valid"] is not None for info in infos)
    has_mesh = all(info["mesh_id"] is not None for info in infos)
    return ShardSet(
        paths=list(paths), grids=grid_source, palette=palette,
        targets=np.concatenate([info["targets"] for info in infos]),
        mesh_ids=np.concatenate([info["mesh_id"] for info in infos]) if has_mesh else None,
        gains=np.concatenate([info["gains"] for info in infos]).astype(np.float32) if has_gains else None,
        valid=np.concatenate([info["valid"] for info in infos]) if has_gains else None,
        view_units=views / np.linalg.norm(views, axis=1, keepdims=True) if has_gains else None,
        view_radius=radius, grid_size=size,
        scene=mixed_scene_record([info["scene"] for info in infos]) if scenes_differ else infos[0]["scene"],
        clouds=cloud_source)


def _valid_views(shard: Shard) -> np.ndarray | None:
    """(N, V) bool: which views pass the overlap rule the shard was labelled with, or None."""
    min_overlap = (shard.info.config or {}).get("oracle", {}).get("min_overlap")
    if not shard.has("overlaps") or min_overlap is None:
        return None
    return shard["overlaps"].astype(np.float64) >= float(min_overlap)


def load_view_states(paths: list[Path], poses: Literal["refuse", "nearest"] = "refuse") -> np.ndarray:
    """(N, V) bool view states of every sample of ``paths`` in order (``view_state`` per shard);
    ShardError naming the shard when one has no ``last_view`` (imported data) or a gap in a run.

    ``poses``: a state reached through a pose that is no candidate view (``last_view`` -1: a
    regression or classification policy's rollout) is refused (a score network's input would be
    wrong), or ``nearest``: that scan counts as the candidate view nearest to its pose in direction
    (``nearest_views``; what ``nbvtrain evaluate`` shows such a planner's own policies)."""
    parts = []
    for path in paths:
        with Shard(path) as shard:
            if not shard.has("last_view"):
                raise ShardError(f"{path}: no last_view (imported data), so no view state: use shards written by "
                                 "nbvdata generate")
            last = shard["last_view"]
            try:
                if poses == "nearest" and len(last) and last.min() < 0:
                    last = nearest_views(shard["run"], shard["step"], last, shard["next_pose"][:, :3],
                                         shard["view_positions"])
                parts.append(view_state(shard["run"], shard["step"], last, len(shard["view_positions"])))
            except ValueError as error:
                raise ShardError(f"{path}: {error}") from None
    if len({part.shape[1] for part in parts}) > 1:
        raise ShardError("the shards have different numbers of candidate views: load one kind at a time")
    return np.concatenate(parts)


def nearest_views(run: np.ndarray, step: np.ndarray, last_view: np.ndarray, next_position: np.ndarray,
                  views: np.ndarray) -> np.ndarray:
    """(N,) ``last_view`` with each -1 (a state reached through a pose) replaced by the candidate
    view nearest in direction to that pose: the previous state's (same run, one step before)
    ``next_position`` (N, 3), object frame; ``views`` (V, 3) candidate positions. ValueError when
    the previous state is missing."""
    last = np.array(last_view, dtype=np.int64)
    rows = {(r, s): i for i, (r, s) in enumerate(zip(np.asarray(run).tolist(), np.asarray(step).tolist()))}
    missing = np.flatnonzero(last < 0)
    before = [rows.get((run[i].item(), step[i].item() - 1)) for i in missing]
    for i, row in zip(missing, before):
        if row is None:
            raise ValueError(f"run {run[i]} step {step[i]} was reached through a pose, and its state before (step "
                             f"{step[i] - 1}) is missing: the pose is unknown")
    if len(missing):
        units = views / np.linalg.norm(views, axis=1, keepdims=True)
        last[missing] = nearest_view(np.asarray(next_position, dtype=np.float64)[before], units)
    return last


def split_indices(data: ShardSet, kind: str, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """(train indices, val indices, a description) for a ``random`` or ``mesh`` split.

    random: a seeded permutation of the samples, the first ``round(val_fraction * N)`` held out
    (``nbvdata.schema.manifest.random_split``, as in a published version).
    mesh: whole meshes held out, ``max(1, round(val_fraction * M))`` of the M meshes: the
    published versions' mesh split (``nbvdata.schema.manifest.mesh_split``) with no test part, so with
    the same seed and fractions its val meshes are the ones a version lists for test, then val.
    nbvtrain used to draw its own permutation here (seeded [seed, 0x5EED]): a run made with that
    version holds out other meshes for the same seed (README, Training).
    """
    if kind == "random":
        train, val = random_split(len(data), val_fraction, seed)
        return train, val, {"kind": "random", "seed": seed, "val_fraction": val_fraction}
    if kind != "mesh":
        raise ValueError(f"split={kind!r}: use random or mesh")
    if data.mesh_ids is None:
        raise ShardError("--split mesh needs mesh ids, and these shards have none (imported data): use --split random")
    meshes = np.unique(data.mesh_ids)
    if len(meshes) < 2:
        raise ShardError(f"--split mesh needs at least 2 meshes, the shards hold {len(meshes)}: use --split random")
    parts = mesh_split(meshes, val_fraction, 0.0, seed)
    if isinstance(parts, str):
        raise ShardError(f"--split mesh --val-fraction {val_fraction}: {parts}; hold out fewer meshes")
    is_val = np.isin(data.mesh_ids, parts["val"])
    return (np.flatnonzero(~is_val), np.flatnonzero(is_val),
            {"kind": "mesh", "seed": seed, "val_fraction": val_fraction, "val_meshes": parts["val"].tolist()})


def published_split(published: Published, kind: str) -> tuple[np.ndarray, np.ndarray, dict]:
    """(train indices, val indices, a description) from a published version's ``random`` or
    ``mesh`` split; the indices are the samples of ``published.shard_paths`` loaded in that order.
    The mesh split's test meshes are held out: in neither part."""
    parts = published.split(kind)
    split = published.content["splits"][kind]
    description = {"kind": kind, "manifest": published.label, "seed": published.content["splits"]["seed"]}
    if kind == "mesh":
        description |= {"val_meshes": split["val"]["meshes"], "test_meshes": split["test"]["meshes"]}
    return parts["train"], parts["val"], description


def rotate_quarter_turns(codes: np.ndarray, targets: np.ndarray, turns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotate grids and targets together by ``turns`` x 90 deg about the vertical (z) axis.

    codes (B, n, n, n) indexed [x, y, z] on a grid centred on the object; targets (B, 3);
    turns (B,) in 0..3. A quarter turn maps (x, y) to (-y, x): exact on the voxel lattice.
    """
    codes, targets = codes.copy(), targets.copy()
    for k in (1, 2, 3):
        mine = turns == k
        if not mine.any():
            continue
        codes[mine] = np.rot90(codes[mine], k, axes=(1, 2))
        angle = k * np.pi / 2
        c, s = round(np.cos(angle)), round(np.sin(angle))
        x, y = targets[mine, 0].copy(), targets[mine, 1].copy()
        targets[mine, 0], targets[mine, 1] = c * x - s * y, s * x + c * y
    return codes, targets


def to_grids(codes: np.ndarray, palette: torch.Tensor) -> torch.Tensor:
    """(B, n, n, n) codes -> (B, 1, n, n, n) float32 probabilities on ``palette``'s device."""
    index = torch.from_numpy(codes).to(palette.device, non_blocking=True).long()
    return palette[index].unsqueeze(1)
