"""The sample index of a published version: one CSV row per sample, gzip-compressed
(``NAME-X.Y.Z.samples.csv.gz`` beside the manifest), the table that Croissant's ``samples``
RecordSet loads (``nbvdata.datasets.croissant``) - mlcroissant reads no HDF5.

Columns, in the manifest's sample order (the global index the splits' ranges count)::

    key            int    the sample's global index in the version
    shard          str    its shard, relative to the version's root (the manifest's path)
    row            int    its row in that shard
    mesh_id        str    sha256 of the mesh file (empty for imported data)
    mesh_source    str    the mesh's file name (imported data: the dataset's name)
    run            int    run number within the mesh
    scan           int    scans taken in the state (1 = the start view alone; empty where not recorded)
    mesh_split     str    train, val or test of the mesh split (empty where the version has none)
    random_split   str    train or val of the random split
    nbv_index      int    the ground-truth next-best-view, a row of the shard's view_positions
    coverage       float  observable coverage of the state (empty where not recorded)
    coverage_after float  ... after scanning the NBV

The bytes depend on the shards' arrays alone (fixed column order, the shortest decimals that
read back as the same float32, gzip without a timestamp), so the index of a version is the same file on every machine. Only
``mesh_id``, ``run``, ``step``, ``nbv_index`` and ``coverage`` are read: shards whose other
arrays differ from the published ones (another version of the same states, as ``covers-*`` of
``layouts-*``) give the same index, which ``index_of`` accepts where the manifest's content
digests prove it.
"""

from __future__ import annotations

import csv
import gzip
import io
from pathlib import Path

import numpy as np

from nbvdata.schema.manifest import PARTS, Published, from_ranges, load_manifest, open_verified_for
from nbvdata.schema.shards import PER_SAMPLE, PER_SHARD, Shard

COLUMNS = ("key", "shard", "row", "mesh_id", "mesh_source", "run", "scan", "mesh_split", "random_split",
           "nbv_index", "coverage", "coverage_after")
INTEGER = frozenset({"key", "row", "run", "scan", "nbv_index"})
FLOAT = frozenset({"coverage", "coverage_after"})
READ = frozenset({"mesh_id", "run", "step", "nbv_index", "coverage"})  # the shards' arrays the index holds


def index_name(manifest_path: Path) -> str:
    """``NAME-X.Y.Z.samples.csv.gz`` of the manifest ``NAME-X.Y.Z.json``."""
    return f"{Path(manifest_path).stem}.samples.csv.gz"


def index_of(published_path: Path, root: Path | None = None) -> bytes:
    """The index of the version ``published_path`` (a manifest), read from its shards under
    ``root`` (default: the root it records), each verified first: by its bytes, or where the
    manifest records content digests, by those of the arrays read (the others may differ, be
    missing or be added - a later version's point clouds - or the bytes alone, written by another
    HDF5 library). ManifestError naming the shards that differ."""
    known = {"attributes", *PER_SAMPLE, *PER_SHARD}
    for entry in load_manifest(published_path, root).content["shards"]:
        known |= set(entry.get("content", {}))
    published = open_verified_for(published_path, root, unread=frozenset(known - READ), by_content=True)[0]
    return index_bytes(published)


def index_bytes(published: Published) -> bytes:
    """The gzip-compressed CSV of ``published``'s samples, from its shards (not verified here)."""
    splits = {kind: _part_of(published.content["splits"].get(kind, {}), published.content["totals"]["samples"])
              for kind in ("mesh", "random")}
    sources = {mesh["id"]: mesh["source"] for mesh in published.content["meshes"]}
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(COLUMNS)
    for entry, path in zip(published.content["shards"], published.shard_paths):
        with Shard(path) as shard:
            arrays = {name: shard[name] for name in READ if shard.has(name)}
        rows = entry["samples"]
        mesh_ids = arrays["mesh_id"].astype(str) if "mesh_id" in arrays else np.full(rows, "")
        coverage = arrays.get("coverage")
        for row in range(rows):
            key = entry["first"] + row
            mesh_id = mesh_ids[row]
            writer.writerow([
                key, entry["path"], row, mesh_id, sources.get(mesh_id or None, published.content["source"]),
                int(arrays["run"][row]), _integer(arrays.get("step"), row), splits["mesh"][key],
                splits["random"][key], int(arrays["nbv_index"][row]),
                "" if coverage is None else str(coverage[row, 0]), "" if coverage is None else str(coverage[row, 1])])
    return gzip.compress(text.getvalue().encode("utf-8"), compresslevel=9, mtime=0)


def _integer(values: np.ndarray | None, row: int) -> int | str:
    return "" if values is None else int(values[row])


def _part_of(split: dict, samples: int) -> np.ndarray:
    """(samples,) the part of ``split`` (the manifest's) each sample is in; "" where none."""
    parts = np.full(samples, "", dtype=object)
    if "unavailable" in split:
        return parts
    for part in PARTS:
        if part in split:
            parts[from_ranges(split[part]["ranges"])] = part
    return parts


def read_index(data: bytes) -> list[dict]:
    """The rows of an index file's bytes, typed (empty fields: None)."""
    rows = []
    for raw in csv.DictReader(io.StringIO(gzip.decompress(data).decode("utf-8"))):
        rows.append({name: (None if value == "" else int(value) if name in INTEGER else
                            float(value) if name in FLOAT else value) for name, value in raw.items()})
    return rows
