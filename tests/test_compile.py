"""``python -m skfem_affine compile`` compiles what the scenes use: a run after it compiles nothing."""
import os
import subprocess
import sys
import textwrap

import pytest

ROOT = os.path.normpath(os.path.join(os.path.dirname(__file__), ".."))

#: Steps other scenes than the warm-up's and prints the package kernels numba compiled meanwhile.
COUNT = textwrap.dedent("""
    import numpy as np
    from numba.core import event
    from skfem_affine import _compile_notice
    import skfem_affine as sa

    compiled = []

    class Count(event.Listener):
        def on_start(self, ev):
            d = (ev.data or {}).get("dispatcher")
            if _compile_notice._is_package_kernel(d):
                compiled.append(d.py_func.__qualname__)

        def on_end(self, ev):
            pass

    event.register("numba:compile", Count())
    ball = sa.ElasticBody(sa.scenes.ball_mesh(0.2, 1, center=(0.0, 0.0, 0.3)), velocity=(1.0, 0.0, 0.0),
                          material=sa.NeoHookean(E=1e7, nu=0.3), density=1500.0)
    mattress = sa.ElasticBody(sa.scenes.box_mesh((2.0, 2.0, 0.2), (6, 6, 1), center=(0.0, 0.0, 0.1)),
                              material=sa.NeoHookean(E=2e4, nu=0.3), density=200.0)
    runs = [sa.Simulation([ball, mattress], dt=0.01, gravity=(0, 0, -9.81), colliders=[sa.Plane()],
                          reducer=sa.Affinification(tau_a=0.5, tau_e=1.0)),
            sa.scenes.pills(resolution=1, reducer=sa.Affinification()), sa.scenes.drop(resolution=2, reducer=sa.Affinification()),
            sa.scenes.cantilever(resolution=2, material=sa.Corotational(E=1e5, nu=0.3)),
            sa.scenes.cantilever(resolution=2, material=sa.StVK(E=1e5, nu=0.3), integrator="bdf2")]
    for sim in runs:
        for _ in sim.run(3):
            pass
    print("COMPILED", sorted(set(compiled)))
""")


@pytest.mark.slow
def test_after_the_compile_command_a_run_compiles_nothing(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"),  # an empty cache: everything compiles
           "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    first = subprocess.run([sys.executable, "-m", "skfem_affine", "compile"], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=1800)
    assert first.returncode == 0, first.stderr[-3000:]
    assert "the kernels are in the disk cache" in first.stderr
    (tmp_path / "count.py").write_text(COUNT)
    second = subprocess.run([sys.executable, "count.py"], cwd=tmp_path, env=env, capture_output=True, text=True,
                            timeout=1800)
    assert second.returncode == 0, second.stderr[-3000:]
    assert "COMPILED []" in second.stdout, second.stdout[-2000:]
    assert "compiling the numba kernels" not in second.stderr  # and so no notice


def test_the_compile_command_takes_no_arguments(capsys):
    from skfem_affine.__main__ import main
    assert main(["compile", "--fast"]) == 2
    assert "takes no arguments" in capsys.readouterr().err
