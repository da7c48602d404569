"""Sphinx configuration of the spaceid documentation.

Build (CI runs exactly this; no network is needed)::

    .venv/bin/sphinx-build -W --keep-going -b html docs docs/_build/html

The tutorials in ``tutorials/`` are run by sphinx-gallery at every build and fail it when they
raise; the figures of the figure pages are drawn by ``_figures.py`` at every build.
"""

import sys
from pathlib import Path

import spaceid

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # the build-time figure script

from _figures import make_figures

project = "spaceid"
author = "the spaceid developers"
copyright = "the spaceid developers"
release = version = spaceid.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "sphinx_click",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "_generated", "tutorials", "Thumbs.db", ".DS_Store"]

# --- MyST: Markdown pages with $...$ and $$...$$ math -------------------------------------------
myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist", "substitution"]
myst_substitutions = {"version": release}
myst_heading_anchors = 3

# --- API reference: autodoc + numpydoc ----------------------------------------------------------
autodoc_default_options = {"members": True, "member-order": "bysource"}
autodoc_typehints = "none"  # the numpydoc sections carry types, shapes and units
autosummary_generate = False
numpydoc_show_class_members = False  # dataclass attributes are in the Attributes sections
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_validation_checks = set()

# --- tutorials: sphinx-gallery ------------------------------------------------------------------
sphinx_gallery_conf = {
    "examples_dirs": "tutorials",
    "gallery_dirs": "auto_tutorials",
    "filename_pattern": r"/plot_",
    "within_subsection_order": "FileNameSortKey",
    "abort_on_example_error": True,  # a broken tutorial breaks the build
    "run_stale_examples": True,  # run at every build, not only when the script changed
    "download_all_examples": False,
    "remove_config_comments": True,
    "min_reported_time": 0,
    "write_computation_times": False,  # its page loads scripts from CDNs; the build log has the times
    "reset_modules": ("matplotlib",),
    "capture_repr": (),  # printed output only, not the repr of a cell's last expression
}

# --- HTML ---------------------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"spaceid {release}"
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_show_sourcelink = False


def setup(app):
    app.connect("builder-inited", lambda app: make_figures(HERE / "_generated" / "figures"))
