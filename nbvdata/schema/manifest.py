"""Published dataset versions: a manifest that pins every shard, its verification, and splits.

``nbvdata publish`` writes ``NAME-X.Y.Z.json`` into a manifests folder, and the dataset card
beside it (``nbvdata.datasets.card``). The manifest holds::

    name, version, notes, created        what and when (created: UTC, ISO 8601)
    package_version, git_commit, git_dirty  the nbvdata that published it (commit null outside a checkout)
    schema_version, source               the shard schema; "nbvdata generate" or the imported dataset
    root                                 the shards' folder, relative to the manifest's folder
    config                               the settings that made the data (every shard's ``config``)
    totals                               shards, samples, runs, meshes, bytes
    meshes                               [{id, source, sha256, license, samples, runs}], by source
    shards                               [{path, sha256, bytes, samples, first, runs, content}]: path
                                         relative to root (POSIX), first = global index of its first
                                         sample, content = ``Shard.content_digests()`` (what each
                                         array holds, independent of the file's bytes)
    splits                               {seed, random, mesh}, see ``make_splits``

The samples of a version are numbered in shard order, rows in order (the global index, the
order ``nbvtrain`` loads them in). A split part lists its samples as [start, stop) ranges of
global indices, the mesh split also its mesh ids: no data is copied.

Published versions are immutable. Publishing NAME-X.Y.Z again with the same content (all but
``VOLATILE``: when, by which package and commit, and from where) changes nothing; with other
content it is refused, naming the version to use: a new shard schema is a major bump, other
shards (new meshes or runs), settings or splits a minor one, metadata only (notes, licenses) a
patch.

Imported shards (``nbvdata import-legacy``) have no mesh ids: they publish with the random split
only, the mesh split records why it is missing, and their one "mesh" is the imported dataset.
"""

from __future__ import annotations

import csv
import hashlib
import json
import re
import subprocess
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np

from nbvdata.core.files import sha256_file
from nbvdata.core.text import plural
from nbvdata.schema.shards import GENERATED, Shard, ShardError
from nbvdata.schema.summary import dataset_name

MANIFEST_FORMAT = 1
PARTS = ("train", "val", "test")
VERSION = re.compile(r"(\d+)\.(\d+)\.(\d+)")
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
VOLATILE = frozenset({"created", "package_version", "git_commit", "git_dirty", "root"})
LEVELS = ("patch", "minor", "major")
LEVEL_OF = {"schema_version": "major", "shards": "minor", "totals": "minor", "config": "minor",
            "splits": "minor", "source": "minor"}  # any other key: patch
RULES = {"major": "a new shard schema is a major bump",
         "minor": "new meshes or runs, other shards, settings or splits are a minor bump",
         "patch": "metadata only is a patch bump"}
BUILTIN_LICENSE = "built-in procedural shape (nbvdata.simulation.shapes): no file, no third-party license"
NOT_RECORDED = "not recorded"


class ManifestError(ShardError):
    """A manifest that cannot be written, read or trusted; the one-line message names the fix."""


# ---------------------------------------------------------------------------------------------
# Reading a folder of shards


@dataclass(frozen=True)
class Contents:
    """What a folder of shards holds, as the manifest records it.

    groups : (N,) str mesh id of each sample in global order (the dataset name for imported shards)
    """

    paths: list[Path]
    shards: list[dict]
    meshes: list[dict]
    groups: np.ndarray
    has_mesh_ids: bool
    config: dict
    source: str


def read_contents(root: Path, licenses: dict[str, str]) -> Contents:
    """Hash and count every shard in or below ``root``; ``licenses`` maps mesh file names to licenses.

    Raises ManifestError when the shards mix settings or sources (one version, one setting).
    """
    root = Path(root)
    paths = sorted(root.rglob("*.h5"))
    if not paths:
        raise ManifestError(f"{root}: no .h5 shards in or below this folder; run nbvdata generate --out {root}")
    shards, groups, first = [], [], 0
    meshes: dict[str, dict] = {}
    runs_of: dict[str, set] = defaultdict(set)
    kind = None  # (config, source, has mesh ids) of the first shard: every shard must match it
    for path in paths:
        name = path.relative_to(root).as_posix()
        with Shard(path) as shard:
            info = shard.info
            shard_source = GENERATED if info.source == GENERATED else dataset_name(info.source)
            if kind is None:
                kind, first_name = (info.config, shard_source, shard.has("mesh_id")), name
            elif (info.config, shard_source, shard.has("mesh_id")) != kind:
                raise ManifestError(f"{name} and {first_name} come from different settings or sources: publish "
                                    "one kind of data per version (move the others to another folder)")
            config, source, has_mesh_ids = kind
            if has_mesh_ids:
                group = shard["mesh_id"].astype(str)
                for mesh in info.meshes:
                    meshes.setdefault(mesh["id"], {"id": mesh["id"], "source": mesh["source"],
                                                   "sha256": mesh["sha256"]})
            else:
                group = np.full(len(shard), shard_source)
                meshes.setdefault(shard_source, {"id": None, "source": shard_source, "sha256": None})
            for key, run in zip(group.tolist(), shard["run"].tolist()):
                runs_of[key].add(run)
            samples, shard_runs, content = len(shard), list(info.runs), shard.content_digests()
        groups.append(group)
        shards.append({"path": name, "sha256": sha256_file(path), "bytes": path.stat().st_size,
                       "samples": samples, "first": first, "runs": shard_runs, "content": content})
        first += samples
    groups = np.concatenate(groups)
    keys, counts = np.unique(groups, return_counts=True)
    samples_of = dict(zip(keys.tolist(), counts.tolist()))
    for key, mesh in meshes.items():
        mesh["license"] = _license(mesh["source"], has_mesh_ids, licenses)
        mesh["samples"], mesh["runs"] = samples_of.get(key, 0), len(runs_of[key])
    return Contents(paths, shards, sorted(meshes.values(), key=lambda m: (m["source"], m["id"] or "")),
                    groups, bool(has_mesh_ids), config, source)


def _license(source: str, has_mesh_ids: bool, licenses: dict[str, str]) -> str:
    if not has_mesh_ids:
        return "as the imported dataset states (see its name)"
    if source.startswith("builtin:"):
        return BUILTIN_LICENSE
    return licenses.get(source, licenses.get(Path(source).name, NOT_RECORDED))  # a path under --meshes: its file


def mesh_licenses(mesh_dir: Path) -> dict[str, str]:
    """Mesh file name -> license, from every MESHES.tsv in or below ``mesh_dir``.

    A MESHES.tsv is tab-separated with (at least) the columns ``file`` and ``license_or_origin``,
    as ``../shared/meshes/MESHES.tsv``.
    """
    mesh_dir = Path(mesh_dir)
    if not mesh_dir.is_dir():
        raise ManifestError(f"--meshes {mesh_dir}: no such folder; pass the folder the meshes came from")
    licenses = {}
    for table in sorted(mesh_dir.rglob("MESHES.tsv")):
        with open(table, newline="", encoding="utf-8") as handle:
            rows = csv.DictReader(handle, delimiter="\t")
            if not {"file", "license_or_origin"} <= set(rows.fieldnames or ()):
                raise ManifestError(f"{table}: needs the tab-separated columns file and license_or_origin")
            licenses.update((row["file"], row["license_or_origin"]) for row in rows)
    return licenses


# ---------------------------------------------------------------------------------------------
# Splits


def random_split(n: int, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, val) sorted sample indices: a seeded permutation, the first ``round(val_fraction * n)``
    held out (at least 1, at most n - 1). The paper's per-sample split; ``nbvtrain`` uses it too."""
    order = np.random.default_rng([seed, 0x5EED]).permutation(n)
    n_val = min(max(1, round(val_fraction * n)), n - 1)
    return np.sort(order[n_val:]), np.sort(order[:n_val])


def mesh_split(meshes: np.ndarray, val_fraction: float, test_fraction: float,
               seed: int) -> dict[str, np.ndarray] | str:
    """Distinct mesh ids -> {part: mesh ids}: a seeded permutation, the first ``test_fraction`` of
    the meshes for test, the next ``val_fraction`` for val (each at least 1 unless its fraction is
    0), the rest for train. Returns the reason instead when no mesh would be left to train on."""
    meshes = np.unique(meshes)
    n_test = max(1, round(test_fraction * len(meshes))) if test_fraction else 0
    n_val = max(1, round(val_fraction * len(meshes)))
    if len(meshes) - n_val - n_test < 1:
        return (f"{len(meshes)} meshes cannot give {n_val} validation, {n_test} test and at least 1 "
                "training mesh")
    order = np.random.default_rng([seed, 0x0B1EC7]).permutation(meshes)
    return {"train": np.sort(order[n_test + n_val:]), "val": np.sort(order[n_test:n_test + n_val]),
            "test": np.sort(order[:n_test])}


def make_splits(contents: Contents, seed: int, val_fraction: float, test_fraction: float) -> dict:
    """The manifest's ``splits``: the random (train, val) split and the mesh (train, val, test) split."""
    n = len(contents.groups)
    if n < 2:
        raise ManifestError(f"the shards hold {n} samples, a split needs at least 2: generate more runs")
    train, val = random_split(n, val_fraction, seed)
    splits = {"seed": seed, "random": {"val_fraction": val_fraction, "train": _part(train), "val": _part(val)}}
    if not contents.has_mesh_ids:
        splits["mesh"] = {"unavailable": "the shards hold no mesh ids (imported data)"}
        return splits
    parts = mesh_split(contents.groups, val_fraction, test_fraction, seed)
    if isinstance(parts, str):
        splits["mesh"] = {"unavailable": parts}
        return splits
    splits["mesh"] = {"val_fraction": val_fraction, "test_fraction": test_fraction}
    for part, ids in parts.items():
        splits["mesh"][part] = _part(np.flatnonzero(np.isin(contents.groups, ids)), ids.tolist())
    return splits


def _part(indices: np.ndarray, meshes: list[str] | None = None) -> dict:
    return ({} if meshes is None else {"meshes": meshes}) | {"samples": len(indices), "ranges": to_ranges(indices)}


def to_ranges(indices: np.ndarray) -> list[list[int]]:
    """Sorted distinct indices -> [[start, stop), ...], one per run of consecutive indices."""
    indices = np.asarray(indices, dtype=np.int64)
    if not len(indices):
        return []
    breaks = np.flatnonzero(np.diff(indices) != 1) + 1
    starts, ends = indices[np.r_[0, breaks]], indices[np.r_[breaks - 1, len(indices) - 1]]
    return np.stack([starts, ends + 1], axis=1).tolist()


def from_ranges(ranges: list[list[int]]) -> np.ndarray:
    """[[start, stop), ...] -> (n,) int64 indices."""
    if not ranges:
        return np.empty(0, dtype=np.int64)
    return np.concatenate([np.arange(start, stop, dtype=np.int64) for start, stop in ranges])


# ---------------------------------------------------------------------------------------------
# Reading and verifying a manifest


@dataclass(frozen=True)
class Published:
    """A manifest read from ``path``: its content, the sha256 of its bytes, where its shards are."""

    path: Path
    content: dict
    sha256: str
    root: Path

    @property
    def label(self) -> str:
        return f"{self.content['name']} {self.content['version']}"

    @property
    def identity(self) -> dict:
        """What names this version exactly, for a run to record: name, version, the sha256 of the
        manifest's bytes, and where the manifest and its shards were (absolute)."""
        return {"name": self.content["name"], "version": self.content["version"], "sha256": self.sha256,
                "path": str(self.path.resolve()), "root": str(self.root.resolve())}

    @property
    def shard_paths(self) -> list[Path]:
        """The shards in manifest order: their samples in this order are the global indices."""
        return [self.root / entry["path"] for entry in self.content["shards"]]

    def split(self, kind: str) -> dict[str, np.ndarray]:
        """{part: sorted global sample indices} of the ``random`` or ``mesh`` split."""
        split = self.content["splits"].get(kind)
        if split is None:
            raise ManifestError(f"{self.path}: no {kind!r} split; it has "
                                f"{', '.join(k for k in self.content['splits'] if k != 'seed')}")
        if "unavailable" in split:
            raise ManifestError(f"{self.path}: no {kind} split ({split['unavailable']}): use --split random")
        return {part: from_ranges(split[part]["ranges"]) for part in PARTS if part in split}

    def part_meshes(self, part: str) -> list[dict]:
        """The ``meshes`` records ({id, source, sha256, ...}) of one part of the mesh split, in the
        split's order. ManifestError for another part than train, val or test, a version without
        a mesh split, an empty part, or a part naming a mesh the manifest does not list."""
        if part not in PARTS:
            raise ManifestError(f"--part {part!r}: choose train, val or test (the parts of {self.label}'s mesh split)")
        split = self.content["splits"].get("mesh")
        if not isinstance(split, dict) or "unavailable" in split or not isinstance(split.get(part), dict):
            reason = split.get("unavailable", "none recorded") if isinstance(split, dict) else "none recorded"
            raise ManifestError(f"{self.path}: {self.label} has no mesh split ({reason}): evaluate a version "
                                "generated by nbvdata generate, which records its meshes")
        ids = split[part].get("meshes", [])
        if not ids:
            raise ManifestError(f"{self.label}: the {part} part of its mesh split holds no meshes (published with "
                                f"--{part}-fraction {split.get(f'{part}_fraction', 0)}): choose another part, or "
                                "evaluate a folder of meshes with --meshes DIR alone")
        records = {mesh.get("id"): mesh for mesh in self.content.get("meshes", []) if isinstance(mesh, dict)}
        unlisted = [mesh_id for mesh_id in ids if mesh_id not in records]
        if unlisted:
            raise ManifestError(f"{self.path}: its {part} part names {plural(len(unlisted), 'mesh id')} its meshes "
                                f"do not list (e.g. {str(unlisted[0])[:16]}): restore the published copy")
        return [records[mesh_id] for mesh_id in ids]


def load_manifest(path: str | Path, root: str | Path | None = None) -> Published:
    """Read a manifest; its shards are under ``root``, by default the root it records (relative
    to the manifest's folder)."""
    path = Path(path)
    if not path.is_file():
        raise ManifestError(f"{path}: no such manifest; nbvdata publish SHARDS_DIR --name NAME --version X.Y.Z "
                            "writes one")
    raw = path.read_bytes()
    try:
        content = json.loads(raw)
    except ValueError:
        raise ManifestError(f"{path}: not valid JSON (damaged?): restore the published copy") from None
    if not isinstance(content, dict) or content.get("manifest_format") != MANIFEST_FORMAT:
        raise ManifestError(f"{path}: not an nbvdata manifest of format {MANIFEST_FORMAT}: pass a "
                            "NAME-X.Y.Z.json written by nbvdata publish")
    missing = [key for key in ("name", "version", "root", "totals", "shards", "splits") if key not in content]
    entries = content.get("shards")
    if missing or not isinstance(content["root"], str) or not isinstance(entries, list) or not all(
            isinstance(entry, dict) and {"path", "sha256", "bytes", "samples"} <= entry.keys() for entry in entries):
        raise ManifestError(f"{path}: incomplete manifest ({', '.join(missing) or 'root or shards'} missing or "
                            "malformed): restore the published copy")
    for entry in entries:
        if not stays_inside(entry["path"]):
            raise ManifestError(f"{path}: shard path {str(entry['path'])[:80]!r} leaves the shards' folder; a "
                                "manifest lists its shards relative to its root, inside it: restore the published copy")
    base = Path(root) if root is not None else path.parent / content["root"]
    return Published(path, content, hashlib.sha256(raw).hexdigest(), base)


def stays_inside(name: object) -> bool:
    """Whether a path recorded in a published file (a manifest's shard, a Croissant's contentUrl)
    names a file below its folder: relative, no '..', on POSIX and Windows alike."""
    if not isinstance(name, str) or not name.strip() or "\0" in name:
        return False
    posix, windows = PurePosixPath(name), PureWindowsPath(name)
    return not (posix.is_absolute() or windows.drive or windows.root or ".." in posix.parts or ".." in windows.parts)


@dataclass(frozen=True)
class Problem:
    """A shard that is ``missing``, ``truncated``, ``changed``, ``unreadable``, ``extra`` or (a folder
    checked without a manifest) ``damaged``."""

    kind: str
    path: str
    detail: str = ""
    arrays: tuple[str, ...] = ()  # ``changed`` by content: the arrays (and "attributes") that differ

    def __str__(self) -> str:
        return f"{self.kind}: {self.path}" + (f": {self.detail}" if self.detail else "")


@dataclass(frozen=True)
class Verification:
    published: Published
    problems: list[Problem]
    seconds: float


def verify(path: str | Path, root: str | Path | None = None, by_content: bool = False) -> Verification:
    """Recompute every listed shard's size, sha256 and sample count under the root, and look for
    .h5 files the manifest does not list.

    A shard whose bytes differ is compared by content where the manifest records it (manifests
    from nbvdata >= 0.2): the problem then names the arrays that differ, or says that every
    array and attribute is equal - which ``by_content`` accepts (a regeneration written by
    another HDF5 library or compression, say)."""
    start = time.perf_counter()
    published = load_manifest(path, root)
    if not published.root.is_dir():
        raise ManifestError(f"{published.root}: no such folder, where {published.path} expects its shards: "
                            "pass --root DIR, the folder that holds them")
    problems, listed = [], set()
    inside = published.root.resolve()
    for entry, shard_path in zip(published.content["shards"], published.shard_paths):
        listed.add(entry["path"])
        if shard_path.exists() and not shard_path.resolve().is_relative_to(inside):
            raise ManifestError(f"{published.path}: shard {entry['path']} links to {shard_path.resolve()}, outside "
                                f"{published.root}: pass --root the folder that really holds the shards")
        problem = _check_shard(shard_path, entry, by_content)
        if problem is not None:
            problems.append(problem)
    for extra in sorted(p.relative_to(published.root).as_posix() for p in published.root.rglob("*.h5")):
        if extra not in listed:
            problems.append(Problem("extra", extra, "not in the manifest"))
    return Verification(published, problems, time.perf_counter() - start)


def check_shards(paths: list[Path]) -> list[Problem]:
    """Every shard read whole (``Shard.check``: checksums, gzip streams, value ranges): a
    ``damaged`` problem for each that fails - what ``nbvdata verify`` says of a folder that has no
    manifest."""
    problems = []
    for path in paths:
        try:
            with Shard(path) as shard:
                shard.check()
        except ShardError as error:
            problems.append(Problem("damaged", str(path), str(error).removeprefix(f"{path}: ")))
    return problems


def _check_shard(path: Path, entry: dict, by_content: bool = False) -> Problem | None:
    """What is wrong with a listed shard, or None."""
    name = entry["path"]
    if not path.is_file():
        return Problem("missing", name)
    size = path.stat().st_size
    if size != entry["bytes"] or sha256_file(path) != entry["sha256"]:
        detail = (f"size differs: {size:,} bytes, the manifest lists {entry['bytes']:,}" if size != entry["bytes"]
                  else "sha256 differs from the manifest (same size)")
        try:
            with Shard(path) as shard:
                digests = shard.content_digests() if "content" in entry else None
        except ShardError as error:
            if size < entry["bytes"]:
                return Problem("truncated", name, f"{size:,} of {entry['bytes']:,} bytes; {error}")
            return Problem("changed", name, f"{detail}; {error}")
        if digests is None:
            return Problem("changed", name, detail)
        differ = sorted(key for key in entry["content"].keys() | digests.keys()
                        if entry["content"].get(key) != digests.get(key))
        if differ:
            return Problem("changed", name, f"{detail}; content differs in {', '.join(differ)}", tuple(differ))
        if not by_content:
            return Problem("changed", name, f"{detail}; same content (every array and attribute equal): "
                                            "nbvdata verify --content accepts it")
    try:
        with Shard(path) as shard:
            samples = len(shard)
    except ShardError as error:
        return Problem("unreadable", name, str(error))
    if samples != entry["samples"]:
        return Problem("changed", name, f"{samples} samples, the manifest lists {entry['samples']}")
    return None


SHOWN_PROBLEMS = 3
"""How many of a manifest's problems an error names (``nbvdata verify`` lists every one)."""


def open_verified(path: str | Path, root: str | Path | None = None) -> Published:
    """The manifest, once its shards are verified; ManifestError listing the problems otherwise.

    Extra shards beside the listed ones are no problem here: only the listed ones are read."""
    return open_verified_for(path, root)[0]


def open_verified_for(path: str | Path, root: str | Path | None = None, unread: frozenset[str] = frozenset(),
                      by_content: bool = False) -> tuple[Published, list[Problem]]:
    """``open_verified`` for a reader that never reads the arrays ``unread`` (a grid network, the
    point clouds): a shard whose content differs in those arrays only is accepted, and returned
    with the manifest - (the manifest, the shards accepted so; every other array and the attributes
    equal, so the same samples); ``by_content``: a shard of other bytes whose every array and
    attribute is equal passes too (``verify``'s). ManifestError listing any other problem."""
    verification = verify(path, root, by_content=by_content)
    accepted = [problem for problem in verification.problems
                if problem.kind == "changed" and problem.arrays and set(problem.arrays) <= unread]
    problems = [str(problem) for problem in verification.problems
                if problem.kind != "extra" and problem not in accepted]
    if problems:
        shown = "; ".join(problems[:SHOWN_PROBLEMS]) + (
            f"; and {len(problems) - SHOWN_PROBLEMS} more: nbvdata verify {path} lists them all"
            if len(problems) > SHOWN_PROBLEMS else "")
        raise ManifestError(f"{path}: {plural(len(problems), 'shard')} {'differs' if len(problems) == 1 else 'differ'} "
                            f"from the published {verification.published.label} ({shown}): restore them from a "
                            "good copy, or train on the shards themselves instead of the manifest")
    return verification.published, accepted


# ---------------------------------------------------------------------------------------------
# Publishing


def compare(old: dict, new: dict) -> tuple[str | None, str]:
    """(bump level, what differs in words), or (None, "") when the content is the same."""
    differ = [key for key in sorted((set(old) | set(new)) - VOLATILE) if old.get(key) != new.get(key)]
    if not differ:
        return None, ""
    level = max((LEVEL_OF.get(key, "patch") for key in differ), key=LEVELS.index)
    words = {"schema_version": "shard schema", "config": "settings", "totals": None,
             "shards": _shard_changes(old.get("shards", []), new.get("shards", [])),
             "meshes": _mesh_changes(old.get("meshes", []), new.get("meshes", []))}
    return level, ", ".join(words.get(key, key) for key in differ if words.get(key, key))


def _shard_changes(old: list[dict], new: list[dict]) -> str:
    before, after = ({s["path"]: (s["sha256"], s["samples"]) for s in shards} for shards in (old, new))
    added, removed = len(after.keys() - before.keys()), len(before.keys() - after.keys())
    changed = sum(before[p] != after[p] for p in before.keys() & after.keys())
    return f"shards ({added} added, {removed} removed, {changed} changed)"


def _mesh_changes(old: list[dict], new: list[dict]) -> str | None:
    """Meshes added or removed, or licenses changed; None when only their counts differ (the
    shards' changes say that)."""
    before, after = ({(m["id"], m["source"]): m["license"] for m in meshes} for meshes in (old, new))
    added, removed = len(after.keys() - before.keys()), len(before.keys() - after.keys())
    if added or removed:
        return f"meshes ({added} added, {removed} removed)"
    return "licenses" if before != after else None


def published_versions(manifests_dir: Path, name: str) -> list[tuple[int, int, int]]:
    """The versions of ``name`` with a manifest in ``manifests_dir``."""
    pattern = re.compile(re.escape(name) + r"-(\d+)\.(\d+)\.(\d+)\.json")
    found = (pattern.fullmatch(p.name) for p in Path(manifests_dir).glob(f"{name}-*.json"))
    return sorted(tuple(map(int, m.groups())) for m in found if m)


def next_version(manifests_dir: Path, name: str, level: str) -> str:
    """The highest published version of ``name`` bumped at ``level`` (major, minor or patch)."""
    major, minor, patch = max(published_versions(manifests_dir, name), default=(0, 0, 0))
    bumped = {"major": (major + 1, 0, 0), "minor": (major, minor + 1, 0), "patch": (major, minor, patch + 1)}
    return ".".join(map(str, bumped[level]))


def git_state() -> tuple[str | None, bool | None]:
    """(commit, uncommitted changes?) of the checkout this nbvdata runs from; (None, None) if none."""
    package = Path(__file__).resolve().parents[1]  # the nbvdata folder (this is nbvdata/schema/manifest.py)

    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(package), *args], capture_output=True, text=True,
                              check=True, timeout=30).stdout.strip()
    try:
        top, commit = git("rev-parse", "--show-toplevel", "HEAD").split("\n")
        if Path(top).resolve() / package.name != package:
            return None, None  # an installed copy inside some other repository
        return commit, bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, ValueError, subprocess.SubprocessError):
        return None, None


def dumps(content: dict) -> str:
    """The manifest as JSON: one key per line, lists of numbers (ranges, runs) kept on one line."""
    text = json.dumps(content, indent=1, ensure_ascii=False, allow_nan=False)
    return re.sub(r"\[[^\[\]{}\"]*\]", lambda m: "[" + " ".join(m.group(0)[1:-1].split()) + "]", text) + "\n"


def normalised(content: dict) -> dict:
    """The content as it reads back from JSON (lists, not tuples), so it compares with a read one."""
    return json.loads(json.dumps(content, allow_nan=False))
