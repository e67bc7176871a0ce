"""The documentation: the docs/ site builds with MkDocs in strict mode (a broken link or anchor,
a missing page or a page left out of the nav is a warning, and strict makes it an error), and
the README's relative links and images point at files and headings that exist."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# [text](target) and ![alt](target); the target ends at the first space or closing parenthesis.
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
ELEMENT_ID = re.compile(r'\sid="([^"]+)"')


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built from mkdocs.yml into a temporary folder; fails on any warning."""
    site_dir = tmp_path_factory.mktemp("site")
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
         str(ROOT / "mkdocs.yml"), "--site-dir", str(site_dir)],
        cwd=ROOT, capture_output=True, text=True, timeout=120)
    warnings = [line for line in done.stderr.splitlines() if line.startswith(("WARNING", "ERROR"))]
    assert done.returncode == 0 and not warnings, (
        "mkdocs build --strict failed:\n" + (done.stderr or done.stdout))
    return site_dir


def built_page(site, page):
    """The HTML file MkDocs builds from docs/PAGE.md (PAGE relative to docs/, without .md)."""
    return site / ("index.html" if page == "index" else f"{page}/index.html")


def test_site_builds_strictly_with_every_page(site):
    pages = sorted(p.relative_to(ROOT / "docs").with_suffix("").as_posix()
                   for p in (ROOT / "docs").rglob("*.md"))
    assert "lab/vbd" in pages, "the pattern no longer finds the pages in docs/lab/"
    for page in pages:
        assert built_page(site, page).is_file(), f"docs/{page}.md was not built into the site"


def github_slug(heading):
    """The anchor GitHub gives a README heading: lower case, punctuation dropped, spaces to '-'."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def readme_links():
    text = (ROOT / "README.md").read_text()
    text = re.sub(r"```.*?```", "", text, flags=re.S)   # code blocks hold no links
    return [t for t in LINK.findall(text) if not re.match(r"[a-z]+:", t)]


def test_readme_relative_links_resolve(site):
    readme = (ROOT / "README.md").read_text()
    readme_anchors = {github_slug(h) for h in re.findall(r"^#+ (.+)$", readme, flags=re.M)}
    broken = []
    for target in readme_links():
        path, _, anchor = target.partition("#")
        if not path:
            if anchor not in readme_anchors:
                broken.append(target)
            continue
        if not (ROOT / path).exists():
            broken.append(target)
            continue
        if anchor:
            if not (path.startswith("docs/") and path.endswith(".md")):
                broken.append(target)   # an anchor only into a docs page can be checked
                continue
            built = built_page(site, path[len("docs/"):-len(".md")])
            if anchor not in ELEMENT_ID.findall(built.read_text()):
                broken.append(target)
    assert readme_links(), "the README links nowhere: the pattern no longer finds links"
    assert not broken, f"README links to missing files or headings: {broken}"
