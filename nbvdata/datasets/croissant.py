"""A published version as Croissant 1.1 with the Responsible-AI fields (``NAME-X.Y.Z.croissant.json``
beside the manifest): the metadata format the datasets venues validate (MLCommons; ``mlcroissant
validate``; the NeurIPS datasets track loads the first record of every RecordSet).

What it holds (``croissant(...)``):

- the fields the spec requires: name, description, license, url, creator, datePublished,
  version, citeAs (BibTeX), and ``conformsTo`` Croissant 1.1 and RAI 1.0;
- ``distribution``: the sample index (``nbvdata.datasets.index``, CSV) and one FileObject per
  shard (``application/x-hdf5``) with its sha256 and size - the manifest's;
- RecordSets: ``samples`` (the index's columns, keyed by the global sample index; ``mesh_split``
  refers to ``splits``), ``splits`` (train, val, test as Croissant's split types) and ``meshes``
  (each mesh's id, file, license, runs and samples, as recorded);
- RAI: how the data was collected (simulation, with the settings), its limitations (a simulated
  sensor; procedural or real meshes), the meshes' licenses, no personal information.

mlcroissant has no HDF5 reader: the shards are FileObjects whose hashes ``nbvdata verify``
checks (a RecordSet sourced from an .h5 would validate and then fail to load), and the records
load from the index. The manifest stays the version's identity: the Croissant is derived from it
and ``nbvdata verify`` checks that every sha256 in it equals the manifest's.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from nbvdata.datasets.about import About
from nbvdata.datasets.index import COLUMNS, FLOAT, INTEGER
from nbvdata.schema.manifest import ManifestError, stays_inside
from nbvdata.schema.shards import GENERATED

CONFORMS_TO = ["http://mlcommons.org/croissant/1.1", "http://mlcommons.org/croissant/RAI/1.0"]
CONTEXT = {
    "@language": "en", "@vocab": "https://schema.org/", "citeAs": "cr:citeAs", "column": "cr:column",
    "conformsTo": "dct:conformsTo", "cr": "http://mlcommons.org/croissant/", "rai": "http://mlcommons.org/croissant/RAI/",
    "data": {"@id": "cr:data", "@type": "@json"}, "dataType": {"@id": "cr:dataType", "@type": "@vocab"},
    "dct": "http://purl.org/dc/terms/", "examples": {"@id": "cr:examples", "@type": "@json"},
    "equivalentProperty": "cr:equivalentProperty", "extract": "cr:extract", "field": "cr:field",
    "fileProperty": "cr:fileProperty", "fileObject": "cr:fileObject", "fileSet": "cr:fileSet", "format": "cr:format",
    "includes": "cr:includes", "isLiveDataset": "cr:isLiveDataset", "jsonPath": "cr:jsonPath", "key": "cr:key",
    "md5": "cr:md5", "parentField": "cr:parentField", "path": "cr:path", "recordSet": "cr:recordSet",
    "references": "cr:references", "regex": "cr:regex", "repeated": "cr:repeated", "replace": "cr:replace",
    "samplingRate": "cr:samplingRate", "sc": "https://schema.org/", "separator": "cr:separator", "source": "cr:source",
    "subField": "cr:subField", "transform": "cr:transform"}
INDEX_ID = "samples-index"
SPLITS = {"train": "cr:TrainingSplit", "val": "cr:ValidationSplit", "test": "cr:TestSplit"}
COLUMN_WORDS = {
    "key": "the sample's global index in the version (the manifest's order)",
    "shard": "its shard, relative to the version's root", "row": "its row in that shard",
    "mesh_id": "sha256 of the mesh file", "mesh_source": "the mesh's file name", "run": "run number within the mesh",
    "scan": "scans taken in the state (1 = the start view alone)", "mesh_split": "part of the mesh split",
    "random_split": "part of the random (per-sample) split",
    "nbv_index": "the ground-truth next-best-view, a row of the shard's view_positions",
    "coverage": "observable surface covered in the state (fraction)",
    "coverage_after": "observable surface covered after scanning the NBV (fraction)"}


def croissant_name(manifest_path: Path) -> str:
    """``NAME-X.Y.Z.croissant.json`` of the manifest ``NAME-X.Y.Z.json``."""
    return f"{Path(manifest_path).stem}.croissant.json"


def croissant(content: dict, about: About, index: bytes, index_url: str, shard_url: str) -> dict:
    """The Croissant of the manifest ``content``: ``index`` is the sample index's bytes, found at
    ``index_url``; a shard's contentUrl is ``shard_url`` + its manifest path (both relative to the
    Croissant file)."""
    name, version = content["name"], content["version"]
    distribution = [{"@type": "cr:FileObject", "@id": INDEX_ID, "name": INDEX_ID,
                     "description": "One row per sample: where it is and its labels (gzip-compressed CSV).",
                     "contentUrl": index_url, "encodingFormat": "text/csv", "contentSize": f"{len(index)} B",
                     "sha256": hashlib.sha256(index).hexdigest()}]
    for entry in content["shards"]:
        distribution.append({"@type": "cr:FileObject", "@id": f"shard/{entry['path']}", "name": entry["path"],
                             "contentUrl": shard_url + entry["path"], "encodingFormat": "application/x-hdf5",
                             "contentSize": f"{entry['bytes']} B", "sha256": entry["sha256"]})
    return {
        "@context": CONTEXT, "@type": "sc:Dataset", "conformsTo": CONFORMS_TO, "name": name,
        "alternateName": f"{name} {version}", "description": description(content), "version": version,
        "license": about.license_url, "url": about.url_of(name, version),
        "creator": [_creator(creator) for creator in about.creators],
        "datePublished": content["created"][:10], "citeAs": bibtex(content, about),
        "keywords": list(about.keywords), "isLiveDataset": False,
        "distribution": distribution,
        "recordSet": [_splits(content), _samples(content), _meshes(content)],
        **responsible_ai(content)}


def description(content: dict) -> str:
    """What the version is, in a paragraph (its notes after)."""
    totals = content["totals"]
    what = (f"Reconstruction states labelled with their ground-truth next-best-view (NBV): {totals['samples']:,} "
            f"samples of {totals['meshes']:,} objects in {totals['shards']:,} HDF5 shards. A sample is the "
            "probabilistic occupancy grid of a partly scanned object (OctoMap semantics) and the candidate view "
            "an exhaustive search finds best: the one that adds the most surface while overlapping enough of "
            "what is already seen. Made with the nbv-regression toolkit (nbvdata), after Vasquez-Gomez et al., "
            "'Next-best-view Regression using a 3D Convolutional Neural Network'.")
    return what + (f" {content['notes']}" if content.get("notes") else "")


def bibtex(content: dict, about: About) -> str:
    """A BibTeX entry of the version (Croissant's citeAs)."""
    key = f"{content['name']}-{content['version']}".replace(".", "_")
    authors = " and ".join(creator.name if creator.is_person else f"{{{creator.name}}}"
                           for creator in about.creators)
    return (f"@misc{{{key},\n  title = {{{{{content['name']}}} {content['version']}: next-best-view reconstruction "
            f"states}},\n  author = {{{authors}}},\n  year = {{{content['created'][:4]}}},\n  version = "
            f"{{{content['version']}}},\n  url = {{{about.url_of(content['name'], content['version'])}}},\n  note = "
            f"{{Dataset; manifest {content['name']}-{content['version']}.json}}\n}}")


def _creator(creator) -> dict:
    if creator.is_person:
        family, given = creator.family_given
        entry = {"@type": "sc:Person", "name": f"{given} {family}".strip(), "givenName": given, "familyName": family}
    else:
        entry = {"@type": "sc:Organization", "name": creator.name}
    if creator.orcid:
        entry["identifier"] = f"https://orcid.org/{creator.orcid}"
    if creator.affiliation:
        entry["affiliation"] = {"@type": "sc:Organization", "name": creator.affiliation}
    return entry


def _field(record_set: str, name: str, data_type, description: str, column: str | None = None) -> dict:
    entry = {"@type": "cr:Field", "@id": f"{record_set}/{name}", "name": name, "description": description,
             "dataType": data_type}
    if column is not None:
        entry["source"] = {"fileObject": {"@id": INDEX_ID}, "extract": {"column": column}}
    return entry


def _samples(content: dict) -> dict:
    fields = []
    for column in COLUMNS:
        kind = "sc:Integer" if column in INTEGER else "sc:Float" if column in FLOAT else "sc:Text"
        field = _field("samples", column, kind, COLUMN_WORDS[column], column)
        if column == "mesh_split" and "unavailable" not in content["splits"].get("mesh", {"unavailable": ""}):
            field["dataType"] = ["sc:Text", "cr:Split"]
            field["references"] = {"field": {"@id": "splits/name"}}
        fields.append(field)
    return {"@type": "cr:RecordSet", "@id": "samples", "name": "samples",
            "description": "Every sample of the version, from the sample index; the grids and the other arrays are "
                           "the shard's row (docs/schema.md).",
            "key": {"@id": "samples/key"}, "field": fields}


def _splits(content: dict) -> dict:
    parts = [part for part in SPLITS if any(part in content["splits"].get(kind, {}) for kind in ("mesh", "random"))]
    return {"@type": "cr:RecordSet", "@id": "splits", "name": "splits", "dataType": "cr:Split",
            "description": "The parts of the version's splits: the mesh split holds whole objects out "
                           "(train, val, test), the random split samples (train, val).",
            "key": {"@id": "splits/name"},
            "field": [_field("splits", "name", "sc:Text", "the part's name, as the index spells it"),
                      _field("splits", "url", "sc:URL", "Croissant's split type")],
            "data": [{"splits/name": part, "splits/url": SPLITS[part]} for part in parts]}


def _meshes(content: dict) -> dict:
    return {"@type": "cr:RecordSet", "@id": "meshes", "name": "meshes",
            "description": "The meshes the states were simulated from, with their licenses as recorded when the "
                           "version was published.",
            "key": {"@id": "meshes/source"},
            "field": [_field("meshes", "source", "sc:Text", "the mesh's file name"),
                      _field("meshes", "id", "sc:Text", "sha256 of the mesh file"),
                      _field("meshes", "license", "sc:Text", "its license or origin, as recorded"),
                      _field("meshes", "runs", "sc:Integer", "simulated reconstructions of it"),
                      _field("meshes", "samples", "sc:Integer", "its samples")],
            "data": [{"meshes/source": mesh["source"], "meshes/id": mesh["id"] or "", "meshes/license": mesh["license"],
                      "meshes/runs": mesh["runs"], "meshes/samples": mesh["samples"]} for mesh in content["meshes"]]}


def responsible_ai(content: dict) -> dict:
    """The RAI 1.0 fields, from what the generator recorded."""
    config = content["config"]
    settings = json.dumps(config, sort_keys=True, separators=(",", ":"), allow_nan=False)
    if content["source"] != GENERATED:
        collection = (f"Imported from {content['source']} by nbvdata import-legacy (the authors' published "
                      f"samples, converted); settings: {settings}")
    else:
        collection = ("Simulated with nbvdata generate: a range sensor scans each mesh from views on a sphere "
                      "around it, each scan is integrated into a probabilistic occupancy grid (OctoMap's update "
                      "rule), and every state is labelled by an exhaustive search over the candidate views. No "
                      f"measurement of the real world, no people. Settings (the manifest's config): {settings}")
    licenses = sorted({mesh["license"] for mesh in content["meshes"]})
    kinds = _mesh_kinds(content)
    return {
        "rai:dataCollection": collection,
        "rai:dataCollectionType": ["Simulation"] if content["source"] == GENERATED else ["Secondary data analysis"],
        "rai:dataCollectionRawData": "Mesh files, each listed in the meshes RecordSet with its sha256 and license; "
                                     "the shards are derived from them by simulation alone. Licenses as recorded: "
                                     f"{'; '.join(licenses)}.",
        "rai:dataAnnotationProtocol": "Labels are computed, not annotated: each state's next-best-view is the "
                                      "candidate view with the largest exact gain in observable surface among those "
                                      "overlapping enough of what is already covered.",
        "rai:machineAnnotationTools": ["nbvdata (nbv-regression toolkit)"],
        "rai:dataUseCases": "Training and evaluating next-best-view planners for 3D object reconstruction "
                            "(regression of the NBV, ranking of candidate views, set covers). Validated use: the "
                            "benchmarks of the toolkit's docs. Not for tasks about people.",
        "rai:dataLimitations": "A simulated sensor (ray casting on meshes, no real noise, reflections or "
                               "calibration error) in a 32^3 grid; labels are one-step greedy optima under the "
                               f"recorded overlap rule, not globally optimal plans. Meshes: {kinds}.",
        "rai:dataBiases": "The objects are those of the listed mesh collections (procedural shapes and public 3D "
                          "models of everyday objects, toys, tools and scans); their shapes, scales (each scaled to "
                          "one largest side) and orientations are not a sample of any real scene.",
        "rai:personalSensitiveInformation": "None: the data are simulated scans of object meshes.",
        "rai:dataSocialImpact": "Low: research data for robot perception of objects.",
        "rai:dataReleaseMaintenancePlan": "Published versions never change; a change is published as a new version "
                                          "with its own manifest, card and Croissant.",
        "rai:dataCollectionMissingData": "None by design; runs stop early when no view adds enough surface.",
    }


def _mesh_kinds(content: dict) -> str:
    """How many meshes are procedural (built-in shapes, random URDF objects) and how many not, in words."""
    sources = [mesh["source"] for mesh in content["meshes"]]
    procedural = sum(source.startswith(("builtin:", "random_")) for source in sources)
    real = len(sources) - procedural
    return (f"{procedural:,} procedural (built-in shapes or random URDF objects) and {real:,} real-object or "
            "modelled meshes" if sources else "none recorded")


def croissant_text(document: dict) -> str:
    """The file text of the Croissant ``document`` (JSON, one space a level, UTF-8 as written)."""
    return json.dumps(document, indent=1, ensure_ascii=False, allow_nan=False) + "\n"


def read_croissant(path: Path) -> dict:
    """The Croissant at ``path`` as JSON; ManifestError when it is not one."""
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
        if not isinstance(document, dict) or not all(isinstance(item, dict) and "@id" in item
                                                     for item in document["distribution"]):
            raise ValueError("no distribution of FileObjects")
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ManifestError(f"{path}: not a readable Croissant ({error}): restore it, or write it again with "
                            "nbvdata publish MANIFEST --about FILE") from None
    return document


def check_croissant(path: Path, content: dict) -> list[str]:
    """What in the Croissant at ``path`` disagrees with the manifest ``content`` (each shard's
    sha256 and size, the shards listed) or with the sample index beside it (its sha256); []
    when all agree."""
    files = {item["@id"]: item for item in read_croissant(path)["distribution"]}
    problems, listed = [], set()
    for entry in content["shards"]:
        listed.add(f"shard/{entry['path']}")
        item = files.get(f"shard/{entry['path']}")
        if item is None:
            problems.append(f"lists no shard {entry['path']}")
        elif item.get("sha256") != entry["sha256"] or item.get("contentSize") != f"{entry['bytes']} B":
            problems.append(f"shard {entry['path']}: its sha256 or size differs from the manifest's")
    problems += [f"lists shard {key.removeprefix('shard/')}, which the manifest does not"
                 for key in sorted(files) if key.startswith("shard/") and key not in listed]
    if INDEX_ID in files:
        problems += check_files(path, [files[INDEX_ID]])
    return problems


def check_files(path: Path, items: list[dict] | None = None) -> list[str]:
    """The local files of the Croissant at ``path`` (its FileObjects, or ``items`` of them)
    that are missing or whose sha256 differs from the one it records; [] when all match. A
    contentUrl is relative to the Croissant's folder, inside it; remote ones (http) are not fetched."""
    from nbvdata.core.files import sha256_file

    if items is None:
        items = [item for item in read_croissant(path)["distribution"] if item.get("@type") == "cr:FileObject"]
    problems = []
    for item in items:
        url = str(item.get("contentUrl", ""))
        if url.startswith(("http://", "https://")):
            continue
        local = Path(path).parent / url
        if not stays_inside(url):
            problems.append(f"outside: {url[:80]}: a contentUrl leaves the Croissant's folder; restore the published copy")
        elif not local.is_file():
            problems.append(f"missing: {url}")
        elif sha256_file(local) != item.get("sha256"):
            problems.append(f"changed: {url}: sha256 differs from the Croissant's")
    return problems
