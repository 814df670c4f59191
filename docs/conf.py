"""Sphinx configuration for skelfem's documentation (`make docs` builds it into docs/_build/html)."""
from __future__ import annotations

import importlib
import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(DOCS / "_ext"))
sys.path.insert(0, str(ROOT))

os.environ.setdefault("MPLBACKEND", "Agg")


def _debian_markdown_it() -> None:
    """Use Debian's markdown-it-py 2.x for this process.

    The docs use Debian's myst-parser 0.18 and mdit-py-plugins 0.3, written for
    markdown-it-py 2.x. The venv may hold a newer markdown-it-py (rich, which
    pyvista and meshio pull in, asks for one), which would shadow Debian's and
    break the plugins; Debian's copy is loaded first instead.
    """
    dist = Path("/usr/lib/python3/dist-packages")
    try:
        import markdown_it
    except ImportError:
        return
    if int(markdown_it.__version__.split(".")[0]) < 3 or not (dist / "markdown_it").is_dir():
        return
    for name in [m for m in sys.modules if m == "markdown_it" or m.startswith("markdown_it.")]:
        del sys.modules[name]
    sys.path.insert(0, str(dist))
    try:
        importlib.import_module("markdown_it")
    finally:
        sys.path.remove(str(dist))


_debian_markdown_it()

project = "skelfem"
author = "the skelfem authors"
copyright = "the skelfem authors"
try:
    import tomllib
    release = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
except Exception:      # the version is decoration only
    release = ""
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx_gallery.gen_gallery",
    "studytables",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store", "auto_examples/*.ipynb", "auto_examples/*.py",
                    "auto_examples/*.md5", "auto_examples/*.pickle", "auto_examples/*.zip"]

myst_enable_extensions = ["dollarmath", "colon_fence", "deflist", "smartquotes"]
myst_heading_anchors = 3

# autodoc: the public API; DOLFINx and friends are real imports here (the venv has them)
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
napoleon_google_docstring = True
napoleon_numpy_docstring = True

from sphinx_gallery.sorting import FileNameSortKey  # noqa: E402

sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "within_subsection_order": FileNameSortKey,
    "download_all_examples": False,
    "remove_config_comments": True,
    "abort_on_example_error": False,
    "only_warn_on_example_error": False,
    "plot_gallery": "True",
    "matplotlib_animations": False,
    "image_scrapers": ("matplotlib",),
    "reset_modules": ("matplotlib",),
}

html_theme = "furo"
html_title = "skelfem"
html_static_path = []
html_css_files = []
html_theme_options = {"navigation_with_keys": True}
pygments_style = "sphinx"
pygments_dark_style = "monokai"
