"""The code a user copies runs: every fenced ```python block of README.md and docs/*.md.

Each block runs on its own (a fresh namespace, in an empty temporary working folder), so it must
define everything it uses, as when pasted into a new interpreter. A block that is not meant to
run (a fragment, or one that needs files the repository does not ship) says so and why in its
fence, ```python no-run: <why>; keep those rare. A block that needs an optional extra names it,
```python extra: <name> (tests/test_extras.py runs the others with only the core installed).
"""
import glob
import os
import re

import pytest

from skfem_affine._extras import EXTRA_OF

EXTRAS = set(EXTRA_OF.values())

ROOT = os.path.normpath(os.path.join(os.path.dirname(__file__), ".."))
PAGES = [os.path.join(ROOT, "README.md")] + sorted(glob.glob(os.path.join(ROOT, "docs", "*.md")))
FENCE = re.compile(r"^```python(?P<info>[^\n`]*)\n(?P<code>.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)
NO_RUN = re.compile(r"no-run\b\s*:?\s*(?P<why>.*)")
EXTRA = re.compile(r"extra:\s*(?P<extra>[a-z]+)$")


def blocks(path):
    """``(line, info, code)`` of each fenced python block of a Markdown file (line: the code's first)."""
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    return [(text.count("\n", 0, m.start("code")) + 1, m.group("info").strip(), m.group("code"))
            for m in FENCE.finditer(text)]


def where(path, line):
    return f"{os.path.relpath(path, ROOT)}:{line}"


BLOCKS = [(path, line, info, code) for path in PAGES for line, info, code in blocks(path)]
RUN = [b for b in BLOCKS if not NO_RUN.match(b[2])]


def test_the_blocks_are_found():
    assert os.path.isfile(PAGES[0]) and len(PAGES) > 1
    for path in PAGES:  # a python fence the pattern misses (indented, unclosed) would go untested
        with open(path, encoding="utf-8") as fh:
            opened = sum(1 for line in fh if line.lstrip().startswith("```python"))
        assert opened == len(blocks(path)), f"{where(path, 1)}: a ```python fence is not at column 0 or not closed"
    readme = [b for b in RUN if b[0] == PAGES[0]]
    assert len(readme) >= 5 and any("sa.Simulation" in code for _, _, _, code in readme)


def test_a_block_not_run_says_why():
    for path, line, info, _ in BLOCKS:
        m = NO_RUN.match(info)
        if m:
            assert len(m.group("why").split()) >= 3, f"{where(path, line)}: ```python no-run: <why> (a reason)"
        elif EXTRA.match(info):
            assert EXTRA.match(info).group("extra") in EXTRAS, f"{where(path, line)}: no extra {info!r}"
        else:
            assert info == "", f"{where(path, line)}: unknown fence info {info!r} ('no-run: <why>', 'extra: <name>')"


@pytest.fixture
def registries():
    """Blocks may register methods or scenes (as docs/measuring.md shows): undo that afterwards."""
    from skfem_affine.lab import runners, scenes
    methods, known = dict(runners.METHODS), dict(scenes.SCENES)
    yield
    runners.METHODS.clear()
    runners.METHODS.update(methods)
    scenes.SCENES.clear()
    scenes.SCENES.update(known)


@pytest.mark.parametrize("path, line, code", [(p, n, c) for p, n, _, c in RUN],
                         ids=[where(p, n) for p, n, _, _ in RUN])
def test_block_runs(path, line, code, tmp_path, monkeypatch, capsys, registries):
    monkeypatch.chdir(tmp_path)
    # padded so that a traceback names the Markdown file's own line numbers
    exec(compile("\n" * (line - 1) + code, os.path.relpath(path, ROOT), "exec"), {"__name__": "__main__"})
