"""The shared validators: what they accept, what they refuse, and that the message names the argument."""
from fractions import Fraction

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.body import check_bodies
from skfem_affine.checks import choice, flag, integer, nonnegative, positive, real, real_array
from skfem_affine.lab.scenes import beam_mesh


@pytest.mark.parametrize("value", [0.25, 1, np.float32(0.25), np.int64(3), Fraction(1, 4), np.array(0.5)])
def test_real_accepts_real_numbers(value):
    assert real(value, "x") == float(value) and type(real(value, "x")) is float


@pytest.mark.parametrize("value", ["0.3", b"1", True, np.True_, None, 1 + 0j, [0.3], np.array([0.3]), object()])
def test_real_refuses_what_is_not_a_real_number(value):
    with pytest.raises(TypeError, match="^my_arg must be a real number"):
        real(value, "my_arg")


@pytest.mark.parametrize("value, kwargs", [
    (np.nan, {}), (np.inf, {}), (-np.inf, {}), (10 ** 400, {}),
    (0.0, dict(low=0.0, include_low=False)), (-1e-300, dict(low=0.0)),
    (0.5, dict(high=0.5, include_high=False)), (2.0, dict(low=-1.0, high=1.0)),
])
def test_real_refuses_out_of_range_and_non_finite(value, kwargs):
    with pytest.raises(ValueError, match="^my_arg must"):
        real(value, "my_arg", **kwargs)


def test_real_bounds_and_infinity_when_allowed():
    assert real(0.0, "x", low=0.0) == 0.0 and real(0.5, "x", high=0.5) == 0.5
    assert real(np.inf, "x", finite=False) == np.inf
    with pytest.raises(ValueError, match=r"\(0, inf\)"):
        positive(0, "dt")
    with pytest.raises(ValueError, match=r"\[0, inf\)"):
        nonnegative(-1, "alpha")


@pytest.mark.parametrize("value, expected", [(3, 3), (3.0, 3), (np.int8(3), 3), (np.float64(3.0), 3), (np.array(4), 4)])
def test_integer_accepts_integral_values(value, expected):
    assert integer(value, "n") == expected and type(integer(value, "n")) is int


@pytest.mark.parametrize("value, error", [
    (2.7, ValueError), (np.float32(0.5), ValueError), (np.nan, ValueError), (np.inf, ValueError),
    ("3", TypeError), (True, TypeError), (None, TypeError), ([3], TypeError), (3 + 0j, TypeError),
])
def test_integer_never_truncates(value, error):
    with pytest.raises(error, match="^iterations must be an integer"):
        integer(value, "iterations")


def test_integer_range():
    assert integer(1, "n", low=1, high=1) == 1
    with pytest.raises(ValueError, match=">= 1, got 0"):
        integer(0, "n", low=1)
    with pytest.raises(ValueError, match=r"in \[1, 3\], got 4"):
        integer(4, "n", low=1, high=3)
    with pytest.raises(ValueError, match="<= 3"):
        integer(4, "n", high=3)


def test_flag_and_choice():
    assert flag(True, "f") is True and flag(np.False_, "f") is False and flag(1, "f") is True
    for bad in ("False", "yes", None, 2, 0.0, [True]):
        with pytest.raises(TypeError, match="^f must be True or False"):
            flag(bad, "f")
    assert choice("a", "mode", ("a", "b")) == "a" and choice(None, "mode", (None, "b")) is None
    for bad in ("c", 1, None, True):
        with pytest.raises(ValueError, match="^mode must be one of 'a', 'b'"):
            choice(bad, "mode", ("a", "b"))
    with pytest.raises(ValueError, match="mode"):
        choice(1.0, "mode", (1,))  # types must match: 1.0 is not the integer option 1


def test_real_array():
    a = real_array([[1, 2, 3]], "x", shape=(None, 3), low=0)
    assert a.dtype == float and a.shape == (1, 3)
    b = np.zeros(3)
    assert real_array(b, "x") is not b  # a copy the caller may modify
    assert real_array(np.array([1, Fraction(1, 2)], dtype=object), "x").tolist() == [1.0, 0.5]
    for bad in (["1", "2"], [True, False], [1, None], [1, [2, 3]], [1j], "abc", None, {"a": 1}):
        with pytest.raises(TypeError, match="^x must be"):
            real_array(bad, "x")
    with pytest.raises(ValueError, match=r"x must have shape \(k, 3\), got shape \(3,\)"):
        real_array([1, 2, 3], "x", shape=(None, 3))
    with pytest.raises(ValueError, match=r"x must be finite, got 1 non-finite.*index \(1, 0\)"):
        real_array([[0.0], [np.nan]], "x")
    with pytest.raises(ValueError, match=r"x must lie in \(0, inf\), got -2.0 at index 1"):
        real_array([1.0, -2.0], "x", low=0.0, include_low=False)


def test_check_bodies():
    body = sa.ElasticBody(beam_mesh(1), sa.StVK(E=1e5, nu=0.3))
    other = sa.ElasticBody(beam_mesh(1), sa.StVK(E=1e5, nu=0.3))
    assert check_bodies(body) == [body] and check_bodies((body, other)) == [body, other]
    with pytest.raises(ValueError, match=r"bodies\[0\] and bodies\[2\] are the same ElasticBody"):
        check_bodies([body, other, body])
    assert check_bodies(b for b in [body]) == [body]
    with pytest.raises(TypeError, match="^bodies must be an ElasticBody.*None"):
        check_bodies(None)
    with pytest.raises(ValueError, match="at least one"):
        check_bodies([])
    with pytest.raises(TypeError, match=r"MeshTet.*sa\.ElasticBody\(mesh, material\)"):
        check_bodies(beam_mesh(1))
    with pytest.raises(TypeError, match=r"bodies\[1\] must be an ElasticBody, got MeshTet1"):
        check_bodies([body, beam_mesh(1)])
    with pytest.raises(TypeError, match=r"bodies\[0\].*class ElasticBody"):
        check_bodies([sa.ElasticBody])
    with pytest.raises(TypeError, match="bodies must be"):
        check_bodies(sa.ElasticBody)


@pytest.mark.parametrize("make, error, match", [
    (lambda: sa.solvers.AMGCG(maxiter=2.7), ValueError, "maxiter must be an integer"),
    (lambda: sa.solvers.AMGCG(tol="1e-8"), TypeError, "tol"),
    (lambda: sa.solvers.AMGCG(tol=0.0), ValueError, "tol"),
    (lambda: sa.solvers.AutoSolver(amg_min_dofs=10.5), ValueError, "amg_min_dofs"),
    (lambda: sa.solvers.AutoSolver(amg_max_iterations=0), ValueError, "amg_max_iterations"),
    (lambda: sa.solvers.make_solver(sa.solvers.SuperLU), TypeError, r"class SuperLU: write SuperLU\(\)"),
    (lambda: sa.solvers.make_solver(3), TypeError, "solver must be"),
    (lambda: beam_mesh(2.7), ValueError, "resolution must be an integer"),
    (lambda: sa.scenes.free_body(resolution="2"), TypeError, "resolution"),
    (lambda: sa.scenes.stacked_beams(n=1.5), ValueError, "n must be an integer"),
    (lambda: sa.runners.sweep_taus(grid=2.5), ValueError, "grid must be an integer"),
    (lambda: sa.runners.default_frames(None, frames="10"), TypeError, "frames"),
])
def test_integer_options_are_not_truncated(make, error, match):
    with pytest.raises(error, match=match):
        make()


def test_integral_floats_still_work_where_integers_are_asked():
    assert beam_mesh(2.0).t.shape[1] == beam_mesh(2).t.shape[1]
    assert sa.solvers.AMGCG(maxiter=100.0).maxiter == 100
