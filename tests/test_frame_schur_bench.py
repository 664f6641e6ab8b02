"""benchmarks/frame_schur_bodies.py: the routes to the Delassus operator of several bodies, one round."""
import os
import subprocess
import sys

import pytest

pytest.importorskip("pypardiso")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_bodies_script_times_every_route_in_a_subprocess():
    run = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "frame_schur_bodies.py"), "--bodies", "1", "2",
                          "--reps", "1"], capture_output=True, text=True, timeout=300, env=dict(os.environ, PYTHONPATH=ROOT))
    assert run.returncode == 0, run.stderr[-2000:]
    rows = [line for line in run.stdout.splitlines() if line.startswith("| 1 |") or line.startswith("| 2 |")]
    assert len(rows) == 2 and all(line.count("x)") == 4 for line in rows), run.stdout
