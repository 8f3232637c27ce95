"""MkDocs hooks (``hooks:`` in mkdocs.yml): the README is the site's home page, and the published
manifests' pictures belong to the site.

- ``docs/index.md`` is replaced by ``README.md``, with its links into ``docs/`` made relative to
  this folder (``docs/training.md`` -> ``training.md``): the README is written once, and its links
  work both where the repository is browsed and on the site.
- A page links the README as ``../README.md`` (right where the repository is browsed); here that
  link is read as ``index.md``, the same text.
- ``manifests/*.png`` are copied into the site under ``manifests/``. A page shows one with
  ``![...](../manifests/NAME.png)``, right where the repository is browsed; here that link is
  read as ``manifests/NAME.png``, the copy. README.md links ``manifests/NAME.png`` directly.
"""

import re
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]


def on_files(files, config):
    for path in sorted((ROOT / "manifests").glob("*.png")):
        files.append(File(f"manifests/{path.name}", str(ROOT), config["site_dir"], config["use_directory_urls"]))
    return files


def on_page_markdown(markdown, page, config, files):
    if page.file.src_uri == "index.md":
        return re.sub(r"\]\(docs/", "](", (ROOT / "README.md").read_text(encoding="utf-8"))
    markdown = re.sub(r"\]\(\.\./README\.md", "](index.md", markdown)
    return re.sub(r"\]\(\.\./manifests/", "](manifests/", markdown)


def on_page_content(html, page, config, files):
    """The docstrings introduce their tables with reStructuredText's ``Name::``; show one colon."""
    if page.file.src_uri.startswith("api/"):
        return html.replace("::</p>", ":</p>")
    return html
