"""``nbvdata share MANIFEST --out DIR``: a published version as a folder to upload whole - to a
Hugging Face Hub dataset repository (``huggingface_hub``'s ``upload_folder``) or a Zenodo deposit. It holds

    DIR/README.md                   the card, whose front matter the Hub reads (configs -> data/)
    DIR/NAME-X.Y.Z.png              the card's label-spread figure
    DIR/LICENSE                     the license's terms, where it is "other" (the card links it)
    DIR/CITATION.cff, .zenodo.json  the version's citation files
    DIR/NAME-X.Y.Z.json             the manifest, unchanged: nbvdata verify DIR/NAME-X.Y.Z.json --root DIR/shards
    DIR/NAME-X.Y.Z.croissant.json   the Croissant, its shards' contentUrls under shards/
    DIR/NAME-X.Y.Z.samples.csv.gz   the sample index the Croissant's records load from
    DIR/shards/...                  the published shards, as they are (the dataset of record)
    DIR/data/<split>/<shard>.h5     the Hub's view: train, validation, test

The Hub's ``hdf5`` builder (``datasets`` >= 4.1) reads every dataset of a file as a column, which
requires them all to share their first dimension; the shards also hold per-shard arrays (the
candidate views, the grids' palette, the reference points) and their grids are palette codes.
So ``data/`` holds, per shard and split part (the mesh split where the version has one, else the
random one), the rows of that part with every per-sample array of the shard, the grids decoded
to float32 occupancy probabilities (``grids`` -> ``grid``, an Array3D), and the shard's global
sample indices (``key``, the index's); the per-shard arrays ride along as HDF5 attributes,
which the builder leaves alone. ``datasets.load_dataset(DIR)`` then yields the splits.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from nbvdata.core.text import plural
from nbvdata.datasets.card import hub_split
from nbvdata.datasets.citation import citation_names
from nbvdata.datasets.croissant import croissant_name, croissant_text, read_croissant
from nbvdata.datasets.export import check_new_folder, write_folder
from nbvdata.datasets.index import index_name
from nbvdata.schema.manifest import ManifestError, Published, from_ranges, open_verified
from nbvdata.schema.shards import Shard

PER_SHARD = ("view_positions", "view_poses", "reference_points")  # stored as attributes of each data/ file
SKIPPED = frozenset({"grid_palette", "grids"})  # decoded into ``grid``


@dataclass
class ShareReport:
    """What ``share`` wrote: the folder, and the samples of each Hub split."""

    out: Path
    splits: dict[str, int]
    files: int


def share(manifest_path: str | Path, out: str | Path, root: str | Path | None = None) -> ShareReport:
    """Write the folder of the published version ``manifest_path`` (its shards under ``root``,
    verified first) to the new folder ``out`` (see the module docstring). ManifestError when the
    version has no card front matter, Croissant or citation files yet."""
    manifest_path, out = Path(manifest_path), Path(out)
    check_new_folder(out)
    cff, zenodo = citation_names(manifest_path)
    beside = {"card": manifest_path.with_suffix(".md"), "figure": manifest_path.with_suffix(".png"),
              "croissant": manifest_path.with_name(croissant_name(manifest_path)),
              "index": manifest_path.with_name(index_name(manifest_path)),
              "citation": manifest_path.with_name(cff), "zenodo": manifest_path.with_name(zenodo)}
    missing = [path.name for path in beside.values() if not path.is_file()]
    if missing or not beside["card"].read_text(encoding="utf-8").startswith("---\n"):
        raise ManifestError(f"{manifest_path}: {', '.join(missing) or 'the card front matter'} missing: write them "
                            f"with nbvdata publish {manifest_path} --about FILE (or --license, --creator, --url)")
    published = open_verified(manifest_path, root)
    return write_folder(out, lambda partial: _fill(partial, published, beside))


def _fill(out: Path, published: Published, beside: dict[str, Path]) -> ShareReport:
    content = published.content
    shutil.copyfile(beside["card"], out / "README.md")
    for key in ("figure", "index", "croissant"):
        shutil.copyfile(beside[key], out / beside[key].name)
    shutil.copyfile(beside["citation"], out / "CITATION.cff")
    shutil.copyfile(beside["zenodo"], out / ".zenodo.json")
    shutil.copyfile(published.path, out / published.path.name)
    document = read_croissant(beside["croissant"])
    prefix = f"{content['root']}/"
    for item in document["distribution"]:
        if item["contentUrl"].startswith(prefix):
            item["contentUrl"] = "shards/" + item["contentUrl"].removeprefix(prefix)
    (out / beside["croissant"].name).write_text(croissant_text(document), encoding="utf-8")
    if not str(document.get("license", "")).startswith("https://spdx.org/"):
        (out / "LICENSE").write_text(str(document["license"]) + "\n", encoding="utf-8")
    kind, parts = hub_split(content)
    part_of = np.full(content["totals"]["samples"], "", dtype=object)
    for part, split in parts.items():
        part_of[from_ranges(content["splits"][kind][part]["ranges"])] = split
    counts = dict.fromkeys(parts.values(), 0)
    files = 0
    for entry, path in zip(content["shards"], published.shard_paths):
        target = out / "shards" / entry["path"]
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, target)
        keys = entry["first"] + np.arange(entry["samples"])
        for split in counts:
            rows = np.flatnonzero(part_of[keys] == split)
            if len(rows):
                name = entry["path"].removesuffix(".h5").replace("/", "__") + ".h5"
                hub_file(path, rows, keys[rows], out / "data" / split / name)
                counts[split] += len(rows)
                files += 1
    if sum(counts.values()) != content["totals"]["samples"]:
        raise ManifestError(f"{published.path}: its {kind} split places {sum(counts.values())} of "
                            f"{content['totals']['samples']} samples: restore the published copy")
    return ShareReport(out.with_name(out.name.removesuffix(".partial")), counts, files)


def hub_file(shard_path: Path, rows: np.ndarray, keys: np.ndarray, out: Path) -> None:
    """The rows ``rows`` of a shard as one file of the Hub's view: every per-sample array, the
    grids decoded (``grid``, float32), ``key`` (the global sample indices ``keys``); the
    per-shard arrays as attributes."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with Shard(shard_path) as shard, h5py.File(out, "w", libver=("earliest", "v110"), track_order=False) as f:
        samples = len(shard)
        _dataset(f, "key", np.asarray(keys, dtype=np.int64))
        _dataset(f, "grid", shard.grids(rows).astype(np.float32))
        for name in sorted(shard.file):
            if name in SKIPPED or name in PER_SHARD:
                continue
            array = shard[name]
            if array.ndim and len(array) == samples:
                values = array[rows]
                if values.dtype.kind == "S":  # mesh ids: text the Hub reads as strings
                    values = values.astype(str).astype(object)
                    f.create_dataset(name, data=values, dtype=h5py.string_dtype(), track_times=False)
                else:
                    _dataset(f, name, values)
        for name in PER_SHARD:
            if shard.has(name):
                f.attrs[name] = shard[name]
        f.attrs["shard"] = shard_path.name


def _dataset(f: h5py.File, name: str, values: np.ndarray) -> None:
    chunks = (1, *values.shape[1:]) if values.ndim > 1 else None
    f.create_dataset(name, data=values, chunks=chunks, compression="gzip" if values.ndim > 1 else None,
                     compression_opts=4 if values.ndim > 1 else None, track_times=False)


def describe(report: ShareReport) -> str:
    """The line ``nbvdata share`` prints."""
    splits = ", ".join(f"{split} {plural(count, 'sample', spec=',')}" for split, count in report.splits.items())
    return f"wrote {report.out}: {splits} in {plural(report.files, 'Hub file')} under data/, and the shards as published"
