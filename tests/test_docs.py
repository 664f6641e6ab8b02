"""The documentation site builds with warnings as errors.

The build runs on copies of docs/ and examples/ in a temporary folder (Sphinx writes the
generated API pages and the gallery into its source folder), against this checkout's
package. The gallery is rendered without running the examples (``-D plot_gallery=0``):
tests/test_examples.py runs every one of them already.
"""
import glob
import importlib.util
import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
MISSING = [m for m in ("sphinx", "numpydoc", "sphinx_gallery", "myst_parser", "pydata_sphinx_theme")
           if importlib.util.find_spec(m) is None]


@pytest.mark.slow
@pytest.mark.skipif(bool(MISSING), reason=f"the docs extra is not installed (missing {', '.join(MISSING)}): "
                                           "pip install -e '.[docs]'")
def test_docs_build_without_warnings(tmp_path):
    for folder in ("docs", "examples"):
        shutil.copytree(os.path.join(ROOT, folder), tmp_path / folder,
                        ignore=shutil.ignore_patterns("_build", "auto_examples", "generated", "out", "__pycache__",
                                                      "*.png", "*.gif", "toplevel.inc", "sg_execution_times.rst"))
    for picture in glob.glob(os.path.join(ROOT, "docs", "*.png")):  # the pictures committed with the user guide
        shutil.copy(picture, tmp_path / "docs")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
               MPLBACKEND="Agg")
    html = tmp_path / "html"
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                           "-D", "plot_gallery=0", "docs", str(html)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"sphinx failed:\n{proc.stdout[-5000:]}\n{proc.stderr[-10000:]}"
    pages = {p.name for p in html.rglob("*.html")}
    # the user guide, the API reference (one page per module) and the gallery are all there
    assert {"index.html", "affinification.html", "contact.html", "references.html",
            "reliability.html", "solvers.html", "threads.html"} <= pages
    assert {"skfem_affine.lab.io.html", "skfem_affine.reducers.affine.html", "skfem_affine.threads.html",
            "skfem_affine.reducers.affine.ichol.html", "skfem_affine.integrators.newton_integrator.html",
            "skfem_affine.contact.delassus.html", "skfem_affine.lab.scene_spec.html"} <= pages
    assert {"cantilever.html", "own_mesh.html", "adaptive_subspace.html", "custom_reducer.html"} <= pages
    index = (html / "index.html").read_text()
    assert all(f'href="{page}.html"' in index for page in ("reliability", "solvers", "threads"))  # in the toctree
    api = (html / "api" / "generated" / "skfem_affine.lab.io.html").read_text()
    assert "load_mesh" in api
