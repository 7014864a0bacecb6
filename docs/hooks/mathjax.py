"""MkDocs hook: the site renders its mathematics without the internet.

MathJax 3 comes from the pip package ``sphinx-mathjax-offline`` (the ``docs`` extra), which ships its
files; after the build they are copied into the site at ``javascripts/mathjax/``, where ``mkdocs.yml``'s
``extra_javascript`` loads them, so that a page loads nothing from outside the site (a cluster without
internet access, a built site opened offline). Copied: the TeX/MathML to CommonHTML component, the
TeX extensions it loads on demand, its fonts, and the menu with its accessibility parts.
"""

from __future__ import annotations

import importlib.metadata
import shutil
from pathlib import Path

from mkdocs.exceptions import PluginError

PACKAGE = "sphinx-mathjax-offline"
PARTS = ("tex-mml-chtml.js", "input/tex/extensions", "output/chtml", "ui", "a11y", "sre")
TARGET = "javascripts/mathjax"  # in the site, as mkdocs.yml's extra_javascript names it


def mathjax_files() -> Path:
    """The folder of the packaged MathJax distribution."""
    try:
        dist = importlib.metadata.distribution(PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        raise PluginError(f"the docs render their mathematics with {PACKAGE}: pip install -e '.[docs]'") from None
    return Path(dist.locate_file(f"{PACKAGE}/static/mathjax"))


def on_post_build(config, **kwargs) -> None:
    source, target = mathjax_files(), Path(config["site_dir"]) / TARGET
    target.mkdir(parents=True, exist_ok=True)
    for part in PARTS:
        if (source / part).is_dir():
            shutil.copytree(source / part, target / part, dirs_exist_ok=True)
        else:
            shutil.copy2(source / part, target / part)
