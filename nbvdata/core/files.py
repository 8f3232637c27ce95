"""Files written whole or not at all, and their fingerprints: the few helpers every writer and
reader of the project's files shares (no simulation, no HDF5).

- ``write_atomic``: a small file replaced whole, under a hidden temporary name of this process's
  own (``.NAME.HOST-PID.tmp``), then renamed; ``sweep_temporaries`` deletes the temporaries of
  writers that died (a kill).
- ``process_tag``: HOST-PID, a name part no other process on any machine sharing a folder uses.
- ``sha256_file``: the hex sha256 of a file's bytes (manifests, meshes, checkpoints).
- ``shown_path``: a path as a file that others read may record it (no local roots).
"""

from __future__ import annotations

import hashlib
import os
import re
import socket
from pathlib import Path
from typing import Sequence


def process_tag() -> str:
    """HOST-PID: a name part no other process, on this machine or another, uses."""
    return host_tag() + f"-{os.getpid()}"


def host_tag() -> str:
    """This machine's name as ``process_tag`` spells it."""
    return re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname())


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` of this machine is running."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


TEMPORARY_SUFFIX = ".tmp"


def write_atomic(path: Path, data: str | bytes) -> None:
    """Replace ``path`` by a file holding ``data``, whole or not at all: written under a hidden
    name of this process's own, then renamed, so readers and other writers never see a part."""
    temporary = path.with_name(f".{path.name}.{process_tag()}{TEMPORARY_SUFFIX}")
    if isinstance(data, str):
        temporary.write_text(data, encoding="utf-8")
    else:
        temporary.write_bytes(data)
    os.replace(temporary, path)


def sweep_temporaries(folder: Path, dead: Sequence[str] = ()) -> list[Path]:
    """Delete the hidden temporary files ``.NAME.HOST-PID.tmp`` (``write_atomic``'s, a Rerun
    recording's) of ``folder`` whose writer is gone: those of the files named in ``dead`` (whose
    writer is known dead, e.g. a unit claimed now) from any machine, and the others whose process,
    on this machine, no longer runs. Returns the files deleted."""
    swept = []
    for path in Path(folder).glob(f".*.*{TEMPORARY_SUFFIX}"):
        name, _, tag = path.name[1:].removesuffix(TEMPORARY_SUFFIX).rpartition(".")
        host, _, pid = tag.rpartition("-")
        if name in dead or (host == host_tag() and pid.isdigit() and not process_alive(int(pid))):
            path.unlink(missing_ok=True)
            swept.append(path)
    return swept


def sha256_file(path: str | Path) -> str:
    """Hex sha256 of a file's bytes, read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def shown_path(path: str | Path) -> str:
    """``path`` relative to the working folder where it lies below it, else its name: how a file
    meant for others (a model file, a card) names a local path, never with this machine's roots."""
    path = Path(path)
    try:
        return path.resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return path.name
