"""The documentation cannot rot: README.md stays a short user guide, every relative link in it and
in docs/ reaches a file (and a heading, where it names one) that the site can follow, every page is
in the site's nav, every public module is in the API reference, CI builds the site strictly, and
the site builds from the source alone (mkdocstrings imports nothing, so no torch)."""

import ast
import html
import os
import re
import subprocess
import sys
import unicodedata
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README_LIMIT = 15 * 1024  # bytes: what a user reads first; detail belongs in docs/
PACKAGES = ("nbvdata", "nbvtrain")
LINK = re.compile(r"!?\[[^\[\]]*\]\(([^()\s]+)\)|<img\s[^>]*src=\"([^\"]+)\"")


def _pages() -> list[Path]:
    return [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]


def _prose(text: str) -> str:
    """The text without fenced code blocks, inline code and HTML comments (links there are not links)."""
    text = re.sub(r"^ *```.*?^ *```", "", text, flags=re.M | re.S)
    text = re.sub(r"<!--.*?-->", "", text, flags=re.S)
    return re.sub(r"`[^`\n]*`", "", text)


def _links(path: Path) -> list[str]:
    return [a or b for a, b in LINK.findall(_prose(path.read_text(encoding="utf-8")))]


def _is_relative(target: str) -> bool:
    return not re.match(r"^[a-z][a-z0-9+.-]*:", target, flags=re.I) and not target.startswith("/")


def _heading_texts(path: Path) -> list[str]:
    text = re.sub(r"^ *```.*?^ *```", "", path.read_text(encoding="utf-8"), flags=re.M | re.S)
    texts = []
    for heading in re.findall(r"^#{1,6}\s+(.+?)\s*#*\s*$", text, flags=re.M):
        heading = re.sub(r"\[([^\[\]]*)\]\([^)]*\)", r"\1", heading)  # a link's text
        texts.append(heading.replace("`", "").replace("**", ""))
    return texts


def mkdocs_slug(text: str) -> str:
    """The anchor MkDocs gives a heading (Python-Markdown's toc.slugify)."""
    value = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    value = re.sub(r"[^\w\s-]", "", value).strip().lower()
    return re.sub(r"[-\s]+", "-", value)


def github_slug(text: str) -> str:
    """The anchor GitHub gives a heading when it shows the Markdown file."""
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


def _link_problems(page: Path, target: str) -> list[str]:
    name = page.relative_to(ROOT)
    path_part, _, anchor = target.partition("#")
    linked = (page.parent / path_part).resolve() if path_part else page
    if not linked.exists():
        return [f"{name}: {target}: no such file"]
    problems = []
    if page == ROOT / "README.md":  # the site's home page (docs/hooks.py): only docs/ and the manifests' pictures
        if path_part and not (path_part.startswith("docs/") or re.fullmatch(r"manifests/[^/]+\.png", path_part)):
            problems.append(f"{name}: {target}: the site's home page can link only into docs/ and to manifests/*.png")
    elif path_part:
        inside = DOCS in linked.parents or linked == DOCS
        allowed = linked == ROOT / "README.md"  # the home page (docs/hooks.py)
        if not inside and not allowed and not (linked.parent == ROOT / "manifests" and linked.suffix == ".png"):
            problems.append(f"{name}: {target}: outside docs/, which the site cannot follow "
                            "(only ../README.md and ../manifests/*.png are, by docs/hooks.py)")
    if anchor and linked.suffix == ".md" and DOCS / "api" not in linked.parents:
        texts = _heading_texts(linked)
        for slug in (mkdocs_slug, github_slug):
            if anchor not in {slug(text) for text in texts}:
                problems.append(f"{name}: {target}: no heading of {linked.relative_to(ROOT)} has the anchor "
                                f"#{anchor} ({slug.__name__.replace('_slug', '')}'s rule)")
    return problems


def test_readme_stays_a_short_user_guide():
    size = len((ROOT / "README.md").read_bytes())
    assert size <= README_LIMIT, (f"README.md is {size:,} bytes, over {README_LIMIT:,}: move detail into a "
                                  "docs/ page and link it from the README")


def test_every_relative_link_reaches_a_file_and_heading_the_site_can_follow():
    problems, count = [], 0
    for page in _pages():
        for target in _links(page):
            if _is_relative(target):
                count += 1
                problems += _link_problems(page, target)
    assert count > 50, f"only {count} relative links found: is the link pattern still right?"
    assert not problems, "\n".join(problems)


def test_the_link_check_catches_a_broken_file_heading_and_exit_from_docs(tmp_path):
    """The checks above, on links that must fail (so a passing run means something)."""
    page = DOCS / "simulation.md"
    assert _link_problems(page, "oracle.md") == [] and _link_problems(page, "#the-scene") == []
    assert _link_problems(page, "generating.md#off-the-oracles-path-exploration-and-learned-policy-rollouts") == []
    assert "no such file" in _link_problems(page, "no-such-page.md")[0]
    assert len(_link_problems(page, "oracle.md#no-such-heading")) == 2
    assert "outside docs/" in _link_problems(page, "../configs/default.yaml")[0]
    assert _link_problems(page, "../manifests/builtin-shapes-1.3.0.png") == []
    assert _link_problems(page, "../README.md#quick-start") == []
    assert "home page" in _link_problems(ROOT / "README.md", "configs/default.yaml")[0]
    # Where MkDocs and GitHub would give a heading different anchors, a link to it fails one of the two.
    assert mkdocs_slug("generate -> inspect") == "generate-inspect" != github_slug("generate -> inspect")
    assert mkdocs_slug("Training: nbvtrain") == github_slug("Training: nbvtrain") == "training-nbvtrain"


def _nav_files(entries) -> list[str]:
    files = []
    for entry in entries:
        if isinstance(entry, str):
            files.append(entry)
        elif isinstance(entry, dict):
            for value in entry.values():
                files += _nav_files(value) if isinstance(value, list) else [value]
    return files


def test_every_page_is_in_the_nav():
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    nav = _nav_files(config["nav"])
    pages = sorted(str(path.relative_to(DOCS)) for path in DOCS.rglob("*.md"))
    missing = sorted(set(pages) - set(nav))
    assert not missing, f"add these pages to `nav:` in mkdocs.yml: {missing}"
    assert not sorted(set(nav) - set(pages)), "mkdocs.yml's nav names pages that do not exist"
    assert len(nav) == len(set(nav)), "a page is in the nav twice"


def _public_modules(package: str) -> list[str]:
    """Every public module and folder of ``package``, by its dotted name under it (``core.config``, ``planners``)."""
    names = []
    for path in (ROOT / package).rglob("*.py"):
        parts = path.relative_to(ROOT / package).with_suffix("").parts
        parts = parts[:-1] if parts[-1] == "__init__" else parts
        if parts and not any(part.startswith("_") for part in parts):
            names.append(".".join(parts))
    return sorted(names)


def _source(package: str, name: str) -> Path:
    path = ROOT / package / name.replace(".", "/")
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_module_is_in_the_api_reference(package):
    listed = re.findall(rf"^::: ({package}(?:\.\w+)+)\s*$", (DOCS / "api" / f"{package}.md").read_text(),
                        flags=re.M)
    expected = [f"{package}.{name}" for name in _public_modules(package)]
    assert sorted(listed) == expected, (f"docs/api/{package}.md should list `::: MODULE` for exactly "
                                        f"{expected}; it lists {listed}")


def test_ci_builds_the_site_strictly_with_what_the_test_extra_installs():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert set(extras["docs"]) <= set(extras["test"]), "the test extra must install the docs extra's tools"
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    tests = ci.index("# The README's test command:") + 1
    assert any("mkdocs build --strict" in line and not line.startswith("#") for line in ci[tests + 1:])


def test_the_site_builds_strictly_from_the_source_alone(tmp_path):
    """mkdocs build --strict with torch, numba and open3d unimportable: the API reference is read from
    the source (griffe), and every public module's docstring is on its page."""
    pytest.importorskip("mkdocs", reason='the docs tools are not installed: pip install -e ".[docs]"')
    pytest.importorskip("mkdocstrings", reason='the docs tools are not installed: pip install -e ".[docs]"')
    pytest.importorskip("material", reason='the docs tools are not installed: pip install -e ".[docs]"')
    code = ("import sys\n"
            "for name in ('torch', 'numba', 'open3d'):\n"
            "    sys.modules[name] = None  # any import of them now raises ImportError\n"
            "from mkdocs.__main__ import cli\n"
            "cli()\n")
    done = subprocess.run([sys.executable, "-c", code, "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True, timeout=600,
                          env=dict(os.environ, NO_MKDOCS_2_WARNING="1"))
    assert done.returncode == 0, done.stdout + done.stderr
    for package in PACKAGES:
        page = (tmp_path / "site" / "api" / package / "index.html").read_text(encoding="utf-8")
        text = re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", "", page)))
        for name in _public_modules(package):
            doc = ast.get_docstring(ast.parse(_source(package, name).read_text(encoding="utf-8")))
            assert doc, f"{package}.{name} has no module docstring"
            first = re.sub(r"\s+", " ", doc.split("\n\n")[0]).replace("`", "")
            assert first in text, f"{package}.{name}'s docstring is not on docs/api/{package}.md: {first[:80]}"
    home = (tmp_path / "site" / "index.html").read_text(encoding="utf-8")
    assert "Quick start" in home and 'href="training/"' in home  # README.md, its docs/ links made relative
