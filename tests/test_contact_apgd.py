"""The matrix-free contact iteration (APGD) against projected Gauss-Seidel on small problems."""
import os
import subprocess
import sys

import numpy as np
import pytest

from skfem_affine.contact import apgd, pgs


def _problem(k=8, seed=3):
    """A dense SPD W (3k x 3k) and free velocities u0 mostly approaching."""
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(3 * k, 3 * k))
    W = B @ B.T / (3 * k) + 0.2 * np.eye(3 * k)
    u0 = rng.normal(size=3 * k)
    u0[0::3] = -np.abs(u0[0::3]) * (rng.random(k) < 0.7) + 0.3 * (rng.random(k) >= 0.7)
    return W, u0


def _counted(W):
    calls = [0]

    def apply(y):
        calls[0] += 1
        return W @ y
    return apply, calls


def test_cone_projection_in_closed_form():
    mu = 0.5
    lam = np.array([1.0, 0.3, 0.0,    # inside: kept
                    -2.0, 0.5, 0.0,   # in the polar cone: 0
                    1.0, 2.0, 0.0])   # outside: onto the rim, (n + mu |t|) / (1 + mu^2)
    out = apgd.cone_projection(lam, mu)
    pn = (1.0 + 0.5 * 2.0) / 1.25
    assert out == pytest.approx([1.0, 0.3, 0.0, 0, 0, 0, pn, mu * pn, 0.0])
    # a projection: idempotent, and the rest is orthogonal to the projected point
    rng = np.random.default_rng(0)
    z = rng.normal(size=30)
    p = apgd.cone_projection(z, mu)
    assert apgd.cone_projection(p, mu) == pytest.approx(p)
    assert np.abs(((z - p).reshape(-1, 3) * p.reshape(-1, 3)).sum(axis=1)).max() < 1e-12
    frictionless = apgd.cone_projection(z, 0.0).reshape(-1, 3)
    assert np.all(frictionless[:, 1:] == 0) and frictionless[:, 0] == pytest.approx(np.maximum(z[0::3], 0))


def test_block_residual_is_pgs_residual():
    W, u0 = _problem()
    rng = np.random.default_rng(1)
    blocks = apgd.diagonal_blocks(W)
    for lam in (np.zeros_like(u0), rng.normal(size=u0.size), apgd.cone_projection(rng.normal(size=u0.size), 0.4)):
        assert apgd.block_residual(blocks, u0 + W @ lam, lam, 0.4) == pytest.approx(
            pgs.contact_residual(W, u0, lam, 0.4), rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("mu", [0.0, 0.3])
@pytest.mark.parametrize("accelerate", [True, False])
def test_same_impulses_as_pgs(mu, accelerate):
    W, u0 = _problem()
    tol = 1e-10
    scale = pgs.velocity_scale(u0)
    exact = np.zeros_like(u0)
    pgs.projected_gauss_seidel(W, u0, exact, mu, 20000, tol)
    apply, calls = _counted(W)
    out = apgd.apgd(apply, u0, np.zeros_like(u0), mu, apgd.diagonal_blocks(W), tol * scale, max_products=20000,
                    accelerate=accelerate)
    assert out.converged and out.products == calls[0]
    normal, cone = pgs.contact_residual(W, u0, out.lam, mu)
    assert max(normal, cone) <= tol * scale
    assert out.W_lam == pytest.approx(W @ out.lam)
    lam = out.lam.reshape(-1, 3)  # in the cones, complementary
    assert np.all(lam[:, 0] >= 0) and np.all(np.linalg.norm(lam[:, 1:], axis=1) <= mu * lam[:, 0] + 1e-12)
    u = (u0 + W @ out.lam).reshape(-1, 3)
    assert np.all(u[:, 0] >= -1e-8 * scale) and np.abs(u[:, 0] * lam[:, 0]).max() < 1e-8 * scale * np.abs(lam).max()
    assert out.lam == pytest.approx(exact, abs=1e-7 * np.abs(exact).max())  # W SPD: one solution


def test_acceleration_and_warm_start_save_products():
    W, u0 = _problem(k=20, seed=5)
    blocks, goal = apgd.diagonal_blocks(W), 1e-8 * pgs.velocity_scale(u0)
    fast = apgd.apgd(lambda y: W @ y, u0, np.zeros_like(u0), 0.3, blocks, goal, max_products=50000)
    slow = apgd.apgd(lambda y: W @ y, u0, np.zeros_like(u0), 0.3, blocks, goal, max_products=50000, accelerate=False)
    assert fast.converged and slow.converged and fast.products < slow.products
    # started at the solution of a nearby problem, fewer products than cold
    warm = apgd.apgd(lambda y: W @ y, u0 * 1.01, fast.lam, 0.3, blocks, goal, max_products=50000)
    cold = apgd.apgd(lambda y: W @ y, u0 * 1.01, np.zeros_like(u0), 0.3, blocks, goal, max_products=50000)
    assert warm.converged and warm.products < cold.products


def test_other_steps_same_solution():
    """Steps from other blocks (here three times W's, as the lumped mass's bound W's from above) reach
    the same impulses."""
    W, u0 = _problem(k=10, seed=2)
    blocks, goal = apgd.diagonal_blocks(W), 1e-9 * pgs.velocity_scale(u0)
    ref = apgd.apgd(lambda y: W @ y, u0, np.zeros_like(u0), 0.3, blocks, goal, max_products=20000)
    out = apgd.apgd(lambda y: W @ y, u0, np.zeros_like(u0), 0.3, blocks, goal, max_products=20000,
                    steps=3 * blocks * np.linspace(1, 2, 10)[:, None, None])
    assert ref.converged and out.converged
    assert out.lam == pytest.approx(ref.lam, abs=1e-6 * np.abs(ref.lam).max())
    with pytest.raises(ValueError, match="blocks"):
        apgd.apgd(lambda y: W @ y, u0, np.zeros_like(u0), 0.3, blocks, goal, steps=blocks[1:])


def test_convex_relaxation_lifts_sliding_contacts():
    """Without De Saxce's shift a sliding contact separates at mu |u_t| (the cone complementarity
    problem): PGS's complementarity residual is then not met."""
    W = np.diag([1.0, 1.0, 1.0])
    u0 = np.array([-1.0, -3.0, 0.0])  # pressed down and sliding fast: lam_t at the rim, still sliding
    out = apgd.apgd(lambda y: W @ y, u0, np.zeros(3), 0.5, apgd.diagonal_blocks(W), 1e-12, max_products=5000)
    assert out.converged and out.lam == pytest.approx([1.0, 0.5, 0.0])
    ccp = apgd.apgd(lambda y: W @ y, u0, np.zeros(3), 0.5, apgd.diagonal_blocks(W), 1e-12, max_products=300,
                    coulomb=False)
    # its solution lam = (2, 1, 0) lifts the contact, u = (1, -2, 0): u_n = mu |u_t|, complementarity residual 1
    assert not ccp.converged and min(ccp.history) == pytest.approx(1.0, rel=1e-6)


def test_singular_w_reaches_the_residual():
    """Redundant contacts (W of lower rank, as where rows of J outnumber the touched unknowns): the
    impulses are not unique, the residual is reached all the same."""
    rng = np.random.default_rng(0)
    J = rng.normal(size=(30, 12))  # 10 contacts on 12 unknowns
    W = J @ J.T / 12
    u0 = J @ rng.normal(size=12)  # the free velocities J v of some motion v
    goal = 1e-7 * pgs.velocity_scale(u0)
    out = apgd.apgd(lambda y: W @ y, u0, np.zeros_like(u0), 0.5, apgd.diagonal_blocks(W), goal, max_products=50000)
    assert out.converged and max(pgs.contact_residual(W, u0, out.lam, 0.5)) <= goal


def test_bad_input_names_the_argument():
    W, u0 = _problem(k=2)
    blocks = apgd.diagonal_blocks(W)
    with pytest.raises(TypeError, match="apply"):
        apgd.apgd(W, u0, np.zeros(6), 0.3, blocks, 1e-6)
    with pytest.raises(ValueError, match="blocks"):
        apgd.apgd(lambda y: W @ y, u0, np.zeros(6), 0.3, blocks[:1], 1e-6)
    with pytest.raises(ValueError, match="lam"):
        apgd.apgd(lambda y: W @ y, u0, np.zeros(5), 0.3, blocks, 1e-6)
    with pytest.raises(ValueError, match="mu"):
        apgd.cone_projection(np.zeros(3), -1.0)
    with pytest.raises(ValueError, match="W"):
        apgd.diagonal_blocks(np.zeros((4, 4)))


def test_bound_script_reaches_pgs_residual_through_the_factor_in_a_subprocess():
    """benchmarks/matrix_free_bound.py on the smallest stacked beams: W y through the plain factor equals
    the dense W's, and APGD from the warm start reaches PGS's residual on both frames."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    run = subprocess.run([sys.executable, os.path.join(root, "benchmarks", "matrix_free_bound.py"), "--scene",
                          "stacked_beams", "--cells", "1", "--frame", "12", "--reps", "1", "--max-products", "300"],
                         capture_output=True, text=True, timeout=300, env=dict(os.environ, PYTHONPATH=root))
    assert run.returncode == 0, run.stderr[-2000:]
    out = run.stdout
    assert float(out.split("against the dense W: ")[1].split(";")[0]) < 1e-12, out
    table = out.split("| frame | goal")[1].splitlines()[2:4]
    assert len(table) == 2 and all(row.split("|")[7].strip().isdigit() for row in table), out  # APGD warm reached
