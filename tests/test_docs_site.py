"""The built documentation site loads nothing from outside itself: no script, style sheet, font, image
or frame from another host (links in the text, to papers, are not loaded and not checked), and the
MathJax it renders the mathematics with is in the site."""

import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

ROOT = Path(__file__).resolve().parents[1]
# (tag, attribute) pairs whose URL the browser loads with the page
LOADED = {("script", "src"), ("link", "href"), ("img", "src"), ("iframe", "src"), ("source", "src"),
          ("video", "src"), ("audio", "src"), ("embed", "src"), ("object", "data")}
NOT_LOADED_LINKS = {"canonical", "alternate", "prev", "next"}  # <link rel=...> that only name a page
CSS_URL = re.compile(r"""url\(\s*['"]?([^'")\s]+)|@import\s+['"]([^'"]+)""")


class _Resources(HTMLParser):
    """The URLs a page loads (`LOADED`)."""

    def __init__(self):
        super().__init__()
        self.urls = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "link" and set((attrs.get("rel") or "").split()) & NOT_LOADED_LINKS:
            return
        self.urls += [attrs[a] for t, a in LOADED if t == tag and attrs.get(a)]


def _external(url: str) -> bool:
    """A URL with a host (``http(s)://host``, ``//host``) or a scheme other than data:."""
    parts = urlsplit(url)
    return bool(parts.netloc) or parts.scheme not in ("", "data")


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    pytest.importorskip("mkdocs")
    out = tmp_path_factory.mktemp("site")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)], cwd=ROOT,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


@pytest.mark.slow  # a whole mkdocs build (~20 s)
def test_built_site_loads_nothing_from_outside(site):
    """No page or style sheet of the built site loads a URL with a host; every local one it loads exists."""
    pages = sorted(site.rglob("*.html"))
    assert len(pages) > 5
    missing, external = [], []
    for page in pages:
        parser = _Resources()
        parser.feed(page.read_text(encoding="utf-8"))
        for url in parser.urls:
            if _external(url):
                external.append((page.relative_to(site), url))
            elif not url.startswith("data:"):
                path = unquote(urlsplit(url).path)  # relative to the page, or to the site's root ("/...")
                target = site / path.lstrip("/") if path.startswith("/") else (page.parent / path).resolve()
                if not target.exists():
                    missing.append((page.relative_to(site), url))
    for sheet in site.rglob("*.css"):
        for match in CSS_URL.finditer(sheet.read_text(encoding="utf-8", errors="replace")):
            url = match.group(1) or match.group(2)
            if _external(url):
                external.append((sheet.relative_to(site), url))
    assert external == [] and missing == []


@pytest.mark.slow
def test_mathematics_is_rendered_by_the_sites_own_mathjax(site):
    """The maths page loads the MathJax copied into the site, fonts included."""
    page = (site / "mathematics" / "index.html").read_text(encoding="utf-8")
    assert 'class="arithmatex"' in page
    parser = _Resources()
    parser.feed(page)
    assert "../javascripts/mathjax/tex-mml-chtml.js" in parser.urls
    assert (site / "javascripts" / "mathjax" / "output" / "chtml" / "fonts" / "woff-v2").is_dir()
