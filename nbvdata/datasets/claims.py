"""Claims on an output folder, so that several ``nbvdata generate`` processes - on one machine, or
on several sharing a filesystem - fill one folder together without losing or repeating work.

A process works on a unit only while it holds the unit's lock, ``DIR/.locks/SHARD.lock``, taken
without waiting: a unit locked by another process is left to it. The shard is written under a
partial name of the writer's own (``SHARD.HOST-PID.partial``) and renamed when complete. A
partial file is deleted only by a process that holds its unit's lock, so only the partial of a
process that died (a kill, a crash) is ever deleted, never a live one's. Changes to the folder's
own files (``config.yaml``, ``failures.tsv``) are made under the short folder lock,
``DIR/.locks/folder.lock``.

The locks are ``filelock`` locks: ``flock``, which the kernel releases when a process dies (NFS
maps it to POSIX locks); on a filesystem without ``flock``, filelock's soft lock files, which a
later process breaks when their owner is no longer alive. The lock files stay (empty, a few
bytes each): delete ``DIR/.locks`` when no job runs, if they are in the way.
"""

from __future__ import annotations

import contextlib
from collections import defaultdict
from pathlib import Path
from typing import Iterator

from filelock import FileLock, Timeout

from nbvdata.core.config import ConfigError
from nbvdata.core.files import process_tag
from nbvdata.schema.shards import PARTIAL_SUFFIX

LOCKS_DIR = ".locks"
FOLDER_LOCK = "folder.lock"
FOLDER_WAIT = 60.0  # seconds; the folder lock is held for milliseconds at a time


def _lock_file(out_dir: Path, name: str) -> Path:
    locks = Path(out_dir) / LOCKS_DIR
    locks.mkdir(parents=True, exist_ok=True)
    return locks / name


@contextlib.contextmanager
def folder_lock(out_dir: Path) -> Iterator[None]:
    """Hold the folder lock while the block runs (waits up to ``FOLDER_WAIT`` seconds for it)."""
    path = _lock_file(out_dir, FOLDER_LOCK)
    lock = FileLock(path)
    try:
        lock.acquire(timeout=FOLDER_WAIT)
    except Timeout:
        raise ConfigError(f"{path}: another nbvdata process has held this lock for {FOLDER_WAIT:.0f} s; let it "
                          "finish, or delete the file if no nbvdata job uses the folder") from None
    try:
        yield
    finally:
        lock.release()


@contextlib.contextmanager
def claim(out_dir: Path, shard_name: str) -> Iterator[bool]:
    """Hold the lock of the unit writing ``shard_name`` while the block runs; yields False, at once,
    when another process holds it (then nothing is held)."""
    lock = FileLock(_lock_file(out_dir, f"{shard_name}.lock"))
    try:
        lock.acquire(blocking=False)
    except Timeout:
        yield False
        return
    try:
        yield True
    finally:
        lock.release()


def partial_path(shard: Path) -> Path:
    """Where this process writes ``shard`` before renaming it: a name no other process uses."""
    return shard.with_name(f"{shard.name}.{process_tag()}{PARTIAL_SUFFIX}")


def shard_of_partial(name: str) -> str:
    """The shard a partial file belongs to: ``SHARD.HOST-PID.partial`` or (older) ``SHARD.partial``."""
    stem = name.removesuffix(PARTIAL_SUFFIX)
    return stem if stem.endswith(".h5") else stem.rsplit(".", 1)[0]


def drop_partials(out_dir: Path, shard_name: str) -> None:
    """Delete the partial files of ``shard_name``: the caller holds its claim, so they are dead
    processes' leftovers."""
    for path in Path(out_dir).glob(f"*{PARTIAL_SUFFIX}"):
        if shard_of_partial(path.name) == shard_name:
            path.unlink(missing_ok=True)


def sweep_partials(out_dir: Path) -> None:
    """Delete every partial file of ``out_dir`` whose unit no live process holds (left by a kill)."""
    shards = defaultdict(list)
    for path in Path(out_dir).glob(f"*{PARTIAL_SUFFIX}"):
        shards[shard_of_partial(path.name)].append(path)
    for shard_name, paths in shards.items():
        with claim(out_dir, shard_name) as mine:
            if mine:
                for path in paths:
                    path.unlink(missing_ok=True)
