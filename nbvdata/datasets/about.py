"""Who publishes a dataset version, under which license, and where it is shared: what the
venues that index datasets require beside the data itself (Croissant's ``license``, ``creator``
and ``url``; the Hub card's ``license``; CITATION.cff's ``authors``; Zenodo's ``creators``).

``nbvdata publish`` takes it from ``--license``, ``--creator`` (repeatable) and ``--url``, or from a
small YAML file (``--about FILE``; flags override it)::

    license: CC-BY-4.0          # an SPDX identifier, or "other" with license_text
    license_text: ...           # what "other" means (required with it)
    creators:                   # people or organisations, in citation order
      - name: Lovelace, Ada     # "Family, Given" for a person, or an organisation's name
        orcid: 0000-0002-1825-0097
        affiliation: ...
    url: https://...            # where the version is shared ({name} and {version} are filled in)
    keywords: [...]

``manifests/about.yaml`` is this project's own, for the versions in ``manifests/``. Nothing is read
from the environment and nothing has a default: a version without a license or a creator is
refused in one line naming the flag.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from nbvdata.schema.manifest import ManifestError

SPDX = re.compile(r"[A-Za-z0-9][A-Za-z0-9.+-]*")
ORCID = re.compile(r"\d{4}-\d{4}-\d{4}-\d{3}[\dX]")
KEYS = {"license", "license_text", "creators", "url", "keywords"}
CREATOR_KEYS = {"name", "orcid", "affiliation"}
KEYWORDS = ("next-best-view", "3d-reconstruction", "active-vision", "occupancy-grid", "robotics")


@dataclass(frozen=True)
class Creator:
    """A person, named "Family, Given" (Zenodo's spelling), or an organisation, named plainly;
    ``orcid`` and ``affiliation`` may be empty."""

    name: str
    orcid: str = ""
    affiliation: str = ""

    @property
    def is_person(self) -> bool:
        return "," in self.name

    @property
    def family_given(self) -> tuple[str, str]:
        """A person's ("Family", "Given")."""
        family, _, given = self.name.partition(",")
        return family.strip(), given.strip()


@dataclass(frozen=True)
class About:
    """A version's publishing settings (see the module docstring)."""

    license: str
    creators: tuple[Creator, ...]
    url: str
    license_text: str = ""
    keywords: tuple[str, ...] = field(default=KEYWORDS)

    def url_of(self, name: str, version: str) -> str:
        """The version's URL: ``url`` with ``{name}`` and ``{version}`` filled in."""
        return self.url.replace("{name}", name).replace("{version}", version)

    @property
    def license_url(self) -> str:
        """SPDX's page of the license; for "other", the text itself (Croissant takes either)."""
        return self.license_text if self.license == "other" else f"https://spdx.org/licenses/{self.license}.html"


def load_about(path: Path | None = None, license: str | None = None, creators: list[str] | None = None,
               url: str | None = None) -> About:
    """The settings of ``path`` (YAML), with the flags given over them. ManifestError, in one
    line naming the flag, for a missing license, creator or url, an unknown key, or a malformed
    value."""
    raw: dict = {}
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise ManifestError(f"--about {path}: no such file; write one (docs/publishing.md) or pass --license, "
                                "--creator and --url")
        try:
            raw = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        except yaml.YAMLError as error:
            raise ManifestError(f"--about {path}: not YAML ({str(error).splitlines()[0]}): fix the file") from None
        if not isinstance(raw, dict):
            raise ManifestError(f"--about {path}: expected a mapping of {', '.join(sorted(KEYS))}")
        unknown = sorted(set(raw) - KEYS)
        if unknown:
            raise ManifestError(f"--about {path}: unknown key {unknown[0]!r}; the keys are {', '.join(sorted(KEYS))}")
    where = f"--about {path}" if path is not None else "the flags"
    license = license or raw.get("license")
    if not license:
        raise ManifestError("no license: pass --license SPDX-ID (e.g. CC-BY-4.0), or license: in --about FILE; "
                            "Croissant, the Hub and Zenodo require one")
    if not isinstance(license, str) or not SPDX.fullmatch(license):
        raise ManifestError(f"--license {license!r}: give an SPDX identifier (e.g. CC-BY-4.0, MIT) or 'other'")
    license_text = str(raw.get("license_text") or "")
    if license == "other" and not license_text:
        raise ManifestError(f"license 'other' needs license_text in --about FILE (what the terms are); {where} "
                            "has none")
    entries = [{"name": name} for name in creators] if creators else raw.get("creators") or []
    if not entries:
        raise ManifestError("no creator: pass --creator NAME (repeat for several), or creators: in --about FILE; "
                            "Croissant, CITATION.cff and Zenodo require one")
    people = []
    for entry in entries:
        if isinstance(entry, str):
            entry = {"name": entry}
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str) or not entry["name"].strip() \
                or set(entry) - CREATOR_KEYS:
            raise ManifestError(f"{where}: a creator is a name, or a mapping of {', '.join(sorted(CREATOR_KEYS))} "
                                f"with a name; got {entry!r}")
        orcid = str(entry.get("orcid") or "").removeprefix("https://orcid.org/")
        if orcid and not ORCID.fullmatch(orcid):
            raise ManifestError(f"{where}: ORCID {orcid!r} of {entry['name']}: expected 0000-0000-0000-0000")
        people.append(Creator(entry["name"].strip(), orcid, str(entry.get("affiliation") or "")))
    url = url or raw.get("url")
    if not url or not isinstance(url, str) or not re.match(r"https?://\S+$", url):
        raise ManifestError(f"no url{f' ({url!r})' if url else ''}: pass --url https://... (where the version is "
                            "shared, e.g. its Hub repository), or url: in --about FILE; Croissant requires one")
    keywords = raw.get("keywords", KEYWORDS)
    if not isinstance(keywords, list | tuple) or not all(isinstance(word, str) for word in keywords):
        raise ManifestError(f"{where}: keywords is a list of words")
    return About(license, tuple(people), url, license_text, tuple(keywords))
