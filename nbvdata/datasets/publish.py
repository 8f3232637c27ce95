"""``nbvdata publish``: a folder of shards becomes a published version - its manifest
(``nbvdata.schema.manifest``, which reads and verifies it), its dataset card with the Hub's front
matter (``nbvdata.datasets.card``), its sample index (``.index``), Croissant (``.croissant``) and
citation files (``.citation``) - written together, never over a published version with other
content. ``describe`` writes all but the manifest for a version already published (its bytes
stay as they are, and so does its identity).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from nbvdata import __version__
from nbvdata.core.files import write_atomic
from nbvdata.datasets.about import About
from nbvdata.datasets.card import front_matter, with_front_matter, write_card
from nbvdata.datasets.citation import citation_cff, citation_names, zenodo_json
from nbvdata.datasets.croissant import croissant, croissant_name, croissant_text
from nbvdata.datasets.index import index_bytes, index_name, index_of
from nbvdata.schema.manifest import (MANIFEST_FORMAT, NAME, RULES, VERSION, ManifestError, Published, compare, dumps,
                                     git_state, load_manifest, make_splits, mesh_licenses, next_version, normalised,
                                     read_contents)
from nbvdata.schema.shards import SCHEMA_VERSION


@dataclass(frozen=True)
class PublishResult:
    """``identical``: the version was already published with this content, nothing was written."""

    path: Path
    content: dict
    identical: bool


def publish(shards_dir: str | Path, name: str, version: str, manifests_dir: str | Path = "manifests",
            notes: str = "", mesh_dir: str | Path | None = None, seed: int = 0, val_fraction: float = 0.2,
            test_fraction: float = 0.2, *, about: About) -> PublishResult:
    """Write ``manifests_dir/NAME-VERSION.json`` for the shards in ``shards_dir``, with its card,
    sample index, Croissant and citation files (``about``: license, creators, url).

    Refuses (ManifestError) an existing NAME-VERSION with other content, naming the next version.
    """
    if not NAME.fullmatch(name):
        raise ManifestError(f"--name {name!r}: use letters, digits, '.', '_' and '-', starting with a letter "
                            "or digit, e.g. builtin-shapes")
    if not VERSION.fullmatch(version):
        raise ManifestError(f"--version {version!r}: use X.Y.Z, e.g. 1.0.0")
    if not 0 < val_fraction < 1 or not 0 <= test_fraction < 1 or val_fraction + test_fraction >= 1:
        raise ManifestError(f"--val-fraction {val_fraction} and --test-fraction {test_fraction}: need "
                            "0 < val, 0 <= test and val + test < 1")
    shards_dir, manifests_dir = Path(shards_dir), Path(manifests_dir)
    if not shards_dir.is_dir():
        raise ManifestError(f"{shards_dir}: no such folder; pass the folder nbvdata generate wrote")
    contents = read_contents(shards_dir, mesh_licenses(mesh_dir) if mesh_dir is not None else {})
    commit, dirty = git_state()
    content = normalised({
        "manifest_format": MANIFEST_FORMAT, "name": name, "version": version, "notes": notes,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "package_version": __version__, "git_commit": commit, "git_dirty": dirty,
        "schema_version": SCHEMA_VERSION, "source": contents.source,
        "root": Path(os.path.relpath(shards_dir.resolve(), manifests_dir.resolve())).as_posix(),
        "config": contents.config,
        "totals": {"shards": len(contents.shards), "samples": len(contents.groups),
                   "runs": sum(mesh["runs"] for mesh in contents.meshes),
                   "meshes": len(contents.meshes), "bytes": sum(shard["bytes"] for shard in contents.shards)},
        "meshes": contents.meshes,
        "shards": contents.shards,
        "splits": make_splits(contents, seed, val_fraction, test_fraction),
    })
    path = manifests_dir / f"{name}-{version}.json"
    if path.exists():
        existing = load_manifest(path).content
        level, what = compare(existing, content)
        if level is None:
            return PublishResult(path, existing, identical=True)
        raise ManifestError(f"{name} {version} is already published ({path}) with other {what}; published "
                            f"versions are immutable: publish this as {next_version(manifests_dir, name, level)} "
                            f"({RULES[level]})")
    manifests_dir.mkdir(parents=True, exist_ok=True)
    write_card(content, path, contents.paths, about)
    write_derived(path, content, about, index_bytes(Published(path, content, "", shards_dir)))
    write_atomic(path, dumps(content))  # last: a manifest exists only with its card and the rest
    return PublishResult(path, content, identical=False)


def describe(manifest_path: str | Path, about: About, root: str | Path | None = None) -> list[Path]:
    """For the published version ``manifest_path``: its card's front matter, and its sample
    index, Croissant and citation files, from its shards under ``root`` (default: the root it
    records; verified first, ``index.index_of``). The manifest is not written. Returns the files
    written."""
    manifest_path = Path(manifest_path)
    content = load_manifest(manifest_path).content
    card = manifest_path.with_suffix(".md")
    if not card.is_file():
        raise ManifestError(f"{card}: the card of {content['name']} {content['version']} is missing: restore the "
                            "published copy")
    written = write_derived(manifest_path, content, about, index_of(manifest_path, root))
    write_atomic(card, with_front_matter(card.read_text(encoding="utf-8"), front_matter(content, about)))
    return [card, *written]


def write_derived(manifest_path: Path, content: dict, about: About, index: bytes) -> list[Path]:
    """The sample index, Croissant, CITATION.cff and .zenodo.json of the version ``content``,
    beside its manifest as NAME-X.Y.Z.samples.csv.gz, .croissant.json, .cff and .zenodo.json."""
    folder, (cff, zenodo) = manifest_path.parent, citation_names(manifest_path)
    document = croissant(content, about, index, index_name(manifest_path), f"{content['root']}/")
    files = {folder / index_name(manifest_path): index,
             folder / croissant_name(manifest_path): croissant_text(document),
             folder / cff: citation_cff(content, about),
             folder / zenodo: zenodo_json(content, about)}
    for path, data in files.items():
        write_atomic(path, data)
    return list(files)
