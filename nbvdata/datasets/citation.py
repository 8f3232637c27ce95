"""How a published version is cited: ``NAME-X.Y.Z.cff`` (Citation File Format 1.2.0, ``type:
dataset``; GitHub and Zenodo read it as ``CITATION.cff``) and ``NAME-X.Y.Z.zenodo.json`` (the
deposit metadata Zenodo reads first as ``.zenodo.json``, ``upload_type: dataset``), beside the
manifest; ``nbvdata share`` writes them under those names into the folder to upload.
"""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from nbvdata.datasets.about import About
from nbvdata.datasets.croissant import description

TITLE = "{name} {version}: next-best-view reconstruction states"
PAPER = {"type": "article", "title": "Next-best-view Regression using a 3D Convolutional Neural Network",
         "authors": [{"family-names": family, "given-names": given} for given, family in (
             ("J. Irving", "Vasquez-Gomez"), ("David", "Troncoso"), ("Israel", "Becerra"), ("Enrique", "Sucar"),
             ("Rafael", "Murrieta-Cid"))],
         "journal": "Machine Vision and Applications", "year": 2021}
ZENODO_OTHER = "other-at"  # Zenodo's "Other (Attribution)", for a license that is no single SPDX one


def citation_names(manifest_path: Path) -> tuple[str, str]:
    """``NAME-X.Y.Z.cff`` and ``NAME-X.Y.Z.zenodo.json`` of the manifest ``NAME-X.Y.Z.json``."""
    stem = Path(manifest_path).stem
    return f"{stem}.cff", f"{stem}.zenodo.json"


def citation_cff(content: dict, about: About) -> str:
    """CITATION.cff of the version (YAML text)."""
    name, version = content["name"], content["version"]
    cff = {"cff-version": "1.2.0", "message": "If you use this dataset, please cite it as below.",
           "type": "dataset", "title": TITLE.format(name=name, version=version), "version": version,
           "date-released": content["created"][:10], "url": about.url_of(name, version),
           "abstract": description(content), "keywords": list(about.keywords),
           "authors": [_cff_author(creator) for creator in about.creators]}
    if about.license != "other":
        cff["license"] = about.license
    cff["references"] = [PAPER]
    return yaml.safe_dump(cff, sort_keys=False, allow_unicode=True, width=100)


def _cff_author(creator) -> dict:
    if creator.is_person:
        family, given = creator.family_given
        author = {"family-names": family, "given-names": given}
    else:
        author = {"name": creator.name}
    if creator.orcid:
        author["orcid"] = f"https://orcid.org/{creator.orcid}"
    if creator.affiliation:
        author["affiliation"] = creator.affiliation
    return author


def zenodo_json(content: dict, about: About) -> str:
    """.zenodo.json of the version (JSON text)."""
    name, version = content["name"], content["version"]
    creators = []
    for creator in about.creators:
        entry = {"name": creator.name}
        if creator.orcid:
            entry["orcid"] = creator.orcid
        if creator.affiliation:
            entry["affiliation"] = creator.affiliation
        creators.append(entry)
    license_text = f" License: {about.license_text}" if about.license == "other" else ""
    deposit = {"upload_type": "dataset", "title": TITLE.format(name=name, version=version),
               "creators": creators, "description": description(content) + license_text,
               "license": ZENODO_OTHER if about.license == "other" else about.license.lower(),
               "publication_date": content["created"][:10], "version": version, "access_right": "open",
               "keywords": list(about.keywords),
               "related_identifiers": [{"identifier": about.url_of(name, version), "relation": "isIdenticalTo",
                                        "resource_type": "dataset"}]}
    return json.dumps(deposit, indent=1, ensure_ascii=False, allow_nan=False) + "\n"
