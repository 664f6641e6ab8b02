"""The documentation site builds with warnings as errors, and reads as a user's manual.

The build runs on copies of docs/ and examples/ in a temporary folder (Sphinx writes the
generated API pages and the gallery into its source folder), against this checkout's
package. The gallery is rendered without running the examples (``-D plot_gallery=0``):
tests/test_examples.py runs every one of them already. The build is nitpicky (every
reference to the package's names must resolve) and needs no network: the intersphinx
inventories fall back to empty local ones.

The text of the README, of the docs sources and of every built page is checked for what a
user cannot follow: commit hashes, issue numbers, branch names, "session"/"agent" wording,
paths into the developers' own folders, and history ("before the fix", "earlier defaults").
"""
import html as html_module
import importlib.util
import os
import re
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
MISSING = [m for m in ("sphinx", "numpydoc", "sphinx_gallery", "myst_parser", "pydata_sphinx_theme")
           if importlib.util.find_spec(m) is None]


# what a page must not say, with a name for the failure message
NOT_FOR_USERS = {
    "commit hash": re.compile(r"(?<![\w./#?=-])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}(?![\w/-])"),
    "commit": re.compile(r"\bcommits?\b(?! to\b)", re.I),
    "issue number": re.compile(r"\bissues? ?#? ?\d", re.I),
    "branch": re.compile(r"\bbranch(es)?\b(?!-free)", re.I),
    "session": re.compile(r"\bsessions?\b", re.I),
    "agent": re.compile(r"\bagents?\b", re.I),
    "developers' folders": re.compile(r"\.\./shared|\bshared/(meshes|papers|notes)|\bworktree", re.I),
    "history": re.compile(r"\b(before|after) (the|this) (fix|change|rule)\b|\bearlier defaults?\b|\bthis round\b"
                          r"|\bthe issue(?:'s)? (asks|says|wants|goal|metric|rule)\b|\bwhat was fixed\b", re.I),
}


def offences(text):
    """The phrases of ``text`` a user's manual must not contain: [(kind, phrase in context)]."""
    found = []
    for kind, pattern in NOT_FOR_USERS.items():
        for m in pattern.finditer(text):
            found.append((kind, text[max(0, m.start() - 50):m.end() + 30].replace("\n", " ")))
    return found


def page_text(markup):
    """The visible text of an HTML page (no scripts, styles or tags)."""
    markup = re.sub(r"<(script|style)\b.*?</\1>", " ", markup, flags=re.S | re.I)
    return html_module.unescape(re.sub(r"<[^>]+>", " ", markup))


def test_the_pattern_catches_history_and_spares_numbers():
    assert {k for k, _ in offences("measured at commit 3ce0625 (issue 14) on branch perf")} == \
        {"commit hash", "commit", "issue number", "branch"}
    assert offences("shared with other agents' jobs, in this session, see ../shared/meshes") != []
    assert offences("before the fix it was 0.77; the earlier default E = 1e5") != []
    clean = ("DOI 10.1145/3687946, 1.2e-1 at 24000 tets, load average 4.5-6, 0x7f3a2b1c8d90, "
             "a branch-free kernel, 2026-11-30, E = 2e7 Pa, deadbeef")
    assert offences(clean) == []


def test_readme_and_docs_sources_read_as_a_manual():
    paths = [os.path.join(ROOT, "README.md")] + sorted(
        os.path.join(ROOT, "docs", f) for f in os.listdir(os.path.join(ROOT, "docs")) if f.endswith((".md", ".rst")))
    paths += sorted(os.path.join(ROOT, "examples", f) for f in os.listdir(os.path.join(ROOT, "examples"))
                    if f.endswith(".py"))
    found = [(os.path.relpath(p, ROOT), kind, where) for p in paths for kind, where in offences(open(p).read())]
    assert not found, "\n".join(f"{p}: {kind}: ...{where}..." for p, kind, where in found)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built once with -W (nitpicky) into a temporary folder: its html folder."""
    if MISSING:
        pytest.skip(f"the docs extra is not installed (missing {', '.join(MISSING)}): pip install -e '.[docs]'")
    tmp_path = tmp_path_factory.mktemp("docs")
    for folder in ("docs", "examples"):
        shutil.copytree(os.path.join(ROOT, folder), tmp_path / folder,
                        ignore=shutil.ignore_patterns("_build", "auto_examples", "generated", "out", "__pycache__",
                                                      "*.gif", "toplevel.inc", "sg_execution_times.rst"))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
               MPLBACKEND="Agg")
    html = tmp_path / "html"
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                           "-D", "plot_gallery=0", "docs", str(html)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"sphinx failed:\n{proc.stdout[-5000:]}\n{proc.stderr[-10000:]}"
    return html


@pytest.mark.slow
def test_docs_build_without_warnings(site):
    html = site
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
    # a page per public class and function, linked from its module's summary table
    assert {"skfem_affine.simulation.Simulation.html", "skfem_affine.lab.io.load_mesh.html",
            "skfem_affine.reducers.affine.affinification.Affinification.html",
            "skfem_affine.lab.plots.trade_plot.html"} <= pages
    assert 'href="skfem_affine.lab.io.load_mesh.html' in api
    # numpydoc sections render as sections: no paragraph turned into a parameter's bold name
    aff = (html / "api" / "generated" / "skfem_affine.reducers.affine.affinification.Affinification.html").read_text()
    assert "The thresholds come first" in aff and "<strong>The thresholds" not in aff
    assert ":class:" not in page_text(aff)
    # names in the prose of the guide and the tutorials link to their API pages
    for page in ("bodies.html", "auto_examples/cantilever.html"):
        text = (html / page).read_text()
        assert re.search(r'href="[^"]*skfem_affine\.simulation\.Simulation\.html', text), page
    # every subpackage says what it holds in more than a word
    lab = page_text((html / "api" / "generated" / "skfem_affine.lab.html").read_text())
    assert "ready-made scenes" in lab


@pytest.mark.slow
def test_built_pages_read_as_a_manual(site):
    found = []
    for page in sorted(site.rglob("*.html")):
        if "_modules" in page.parts or page.name in ("genindex.html", "search.html", "py-modindex.html"):
            continue  # the highlighted sources are code, not prose
        found += [(str(page.relative_to(site)), kind, where) for kind, where in offences(page_text(page.read_text()))]
    assert not found, "\n".join(f"{p}: {kind}: ...{where}..." for p, kind, where in found[:40])
