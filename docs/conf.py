"""Sphinx configuration of the skfem-affine documentation.

Build the site (executes every example of the gallery, a few minutes on 2 cores)::

    pip install -e ".[docs]"
    python -m sphinx -b html docs out/docs

Add ``-D plot_gallery=0`` to render the gallery without running the examples
(what ``tests/test_docs.py`` does: the examples are run by ``tests/test_examples.py``).
"""
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "_ext"))
sys.path.insert(0, os.path.abspath(os.path.join(HERE, "..")))

import skfem_affine  # noqa: E402
from shortnames import empty_inventory  # noqa: E402

project = "skfem-affine"
author = "the skfem-affine developers"
copyright = "2026, the skfem-affine developers"
release = version = skfem_affine.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.intersphinx",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
    "toplevel_api",
    "shortnames",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "**.ipynb_checkpoints", "auto_examples/*.ipynb", "auto_examples/*.py",
                    "auto_examples/*.zip", "auto_examples/*.json", "auto_examples/*.md5"]
templates_path = ["_templates"]

# API reference: a page per module and one per public class and function, generated
# recursively from the package (docs/_templates/autosummary), so that new modules appear
# without editing these sources.
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "none"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks = set()

# Names in prose link to their pages: `Simulation` (reST) is a Python reference, resolved
# among the package's objects by docs/_ext/shortnames.py, as is inline code naming one of them.
# Every reference to the package's own names must resolve (nitpicky; -W makes it an error).
default_role = "py:obj"
nitpicky = True

# Links to Python, NumPy, SciPy, scikit-fem and meshio. Without network access each inventory
# falls back to an empty local one, so that an offline build passes (with -W too): those
# names are then shown as code without links.
EMPTY_INVENTORY = empty_inventory()
intersphinx_mapping = {
    name: (url, (None, EMPTY_INVENTORY)) for name, url in {
        "python": "https://docs.python.org/3",
        "numpy": "https://numpy.org/doc/stable",
        "scipy": "https://docs.scipy.org/doc/scipy",
        "skfem": "https://scikit-fem.readthedocs.io/en/latest",
        "meshio": "https://meshio.readthedocs.io/en/stable",
    }.items()
}
intersphinx_timeout = 10

# Markdown pages (the user guide)
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# The gallery: examples/*.py, each a tutorial that tests/test_examples.py also runs.
sphinx_gallery_conf = {
    "examples_dirs": ["../examples"],
    "gallery_dirs": ["auto_examples"],
    "filename_pattern": r".*\.py",           # run every example (each takes seconds)
    "within_subsection_order": "gallery_order.TutorialOrder",
    "download_all_examples": False,
    "remove_config_comments": True,
    "matplotlib_animations": False,
    "reset_modules": ("matplotlib",),
    "image_scrapers": ("matplotlib",),
    "show_memory": False,
    "min_reported_time": 1,
    "abort_on_example_error": True,
    "capture_repr": (),
    "example_extensions": {".py"},
}

html_theme = "pydata_sphinx_theme"
html_title = "skfem-affine"
html_theme_options = {
    "navbar_align": "left",
    "header_links_before_dropdown": 4,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_static_path = ["_static"]
html_css_files = ["custom.css"]
html_show_sourcelink = False


def _skip_foreign(app, what, name, obj, skip, options):
    """Document only what the package defines (not names it imports, e.g. scipy's cKDTree)."""
    module = getattr(obj, "__module__", None)
    if what == "module" and isinstance(module, str) and not module.startswith("skfem_affine"):
        return True
    return None


def setup(app):
    app.connect("autodoc-skip-member", _skip_foreign)
