r"""An engineer's check: a clamped beam under a tip load, against theory and scikit-fem
====================================================================================

A steel-grey question asked of any dynamics code before trusting it: does a clamped beam under a
tip load come to rest where beam theory and a static finite element solve say, ring at the right
frequency, and carry the right stress at the root? And what does a faster, reduced run cost in
accuracy, in the units an engineer thinks in?

The beam: length L = 1 m, square section b = 0.1 m (I = b^4 / 12), Neo-Hookean E = 10 MPa,
nu = 0.3, rho = 1000 kg/m^3, clamped at x = 0, a tip load P = 10 N (downward, -z) ramped up over
0.3 s, mass-proportional damping so that it comes to rest. No gravity, so that the closed forms
are exact for the load alone.

1. **Static deflection.** Euler-Bernoulli :math:`\delta = P L^3 / (3 E I)`; Timoshenko adds the
   shear term :math:`P L / (\kappa G A)`, :math:`\kappa = 5/6`. scikit-fem's linear static solve on
   the same mesh (linear tetrahedra, the elements the simulation uses) must agree with where the
   damped run comes to rest (the load is small: 2 % of the length); quadratic tetrahedra on the
   same mesh show how far linear ones are from the theory: linear tetrahedra are too stiff in
   bending ("locking"), a discretisation error that shrinks with refinement
   (``--resolution``), not a fault of the time stepping.
2. **First bending frequency**: released from the loaded rest state, the undamped beam swings
   about the straight pose; the period of the tip, against
   :math:`f_1 = 1.8751^2 / (2 \pi L^2) \sqrt{E I / (\rho A)}` and against the first eigenvalue of
   scikit-fem's stiffness and mass matrices on the same mesh.
3. **Root stress**: the bending stress :math:`\sigma_{xx} = M (z - b/2) / I`, with
   :math:`M(x) = P (L - x)` by equilibrium; fitted over the elements between 0.15 L and 0.5 L (away
   from the clamp, whose corners concentrate stress) and extrapolated to the root, against
   :math:`M c / I` with :math:`c = b / 2`.
4. **Speed against accuracy** in the user's units: :class:`~skfem_affine.Affinification` at error
   budgets stated relative to the response (``relative_to="response"``, the default: the largest
   displacement from rest, here the tip deflection), stepped in turn with the full-space run; the
   achieved error over the response, over the scene size, in metres, and the stress error.
   At this size a full solve costs little, so reduction does not pay (it pays from about 20k
   tets, docs/budget.md); the errors are what this example shows.
5. **ParaView**: the loaded run as a series with displacement, velocity and the stresses
   (``cauchy_stress``, ``von_mises_stress``, ...), in ``out/engineer_beam/``.

Linear tetrahedra converge like 1 / k^2 in bending, so the example also runs the loaded beam on
the next finer mesh and extrapolates (Richardson) the deflection and the root stress.

Run ``python examples/engineer_beam.py`` (a few seconds), ``--resolution 4`` for finer meshes.
"""
import argparse
import os

import numpy as np
import scipy.sparse as sp
import skfem
from scipy.sparse.linalg import eigsh
from skfem.helpers import dot
from skfem.models.elasticity import lame_parameters, linear_elasticity

import skfem_affine as sa
from skfem_affine.lab import metrics, runners

L, b, E, nu, rho, P = 1.0, 0.1, 1e7, 0.3, 1000.0, 10.0
I, A = b ** 4 / 12, b * b
G, kappa = E / (2 * (1 + nu)), 5.0 / 6.0
RAMP, DT = 0.3, 0.01
delta_eb = P * L ** 3 / (3 * E * I)
delta_timoshenko = delta_eb + P * L / (kappa * G * A)
f_eb = 1.8751 ** 2 / (2 * np.pi * L ** 2) * np.sqrt(E * I / (rho * A))


def beam_mesh(k):
    """3 k cells over the height (z, the bending direction), one across the width, 10 k along: 180 k^2 tets."""
    return skfem.MeshTet.init_tensor(np.linspace(0, L, 10 * k + 1), np.linspace(0, b, 2), np.linspace(0, b, 3 * k + 1))


def richardson(coarse, fine, k):
    """The value at k -> infinity of a quantity whose error falls like 1 / k^2, from k and k + 1."""
    return (fine * (k + 1) ** 2 - coarse * k ** 2) / ((k + 1) ** 2 - k ** 2)


def tip_of(mesh):
    return np.flatnonzero(mesh.p[0] > L - 1e-9)


def loaded_beam(mesh, reducer=None, load=True, damping=sa.Rayleigh(alpha=8.0, beta=0.0)):
    """The clamped beam with the ramped tip load (``load=False``: no load, e.g. released)."""
    tip = tip_of(mesh)
    per_vertex = np.array([0.0, 0.0, -P / tip.size])
    # the force of a step is evaluated at its start: (t + h) / ramp makes the first step's load nonzero
    forces = [sa.VertexForce(tip, lambda t, x, v: min((t + DT) / RAMP, 1.0) * per_vertex)] if load else None
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=E, nu=nu), density=rho, fixed=mesh.p[0] < 1e-9)
    return sa.Simulation(body, dt=DT, damping=damping, reducer=reducer, solver="direct", forces=forces)


def skfem_static(mesh, element):
    """scikit-fem's linear elastic static solve with the tip load spread over the tip's nodes."""
    basis = skfem.Basis(mesh, skfem.ElementVector(element))
    K = skfem.asm(linear_elasticity(*lame_parameters(E, nu)), basis)
    f = np.zeros(basis.N)
    tip = basis.get_dofs(lambda x: x[0] > L - 1e-9)
    load = tip.nodal["u^3"]
    f[load] = -P / load.size if element.maxdeg == 1 else 0.0
    if element.maxdeg > 1:  # consistent tip traction on quadratic elements: integrate over the tip face
        @skfem.LinearForm
        def traction(v, w):
            return -P / A * v[2]
        fb = skfem.FacetBasis(mesh, skfem.ElementVector(element), facets=mesh.facets_satisfying(
            lambda x: x[0] > L - 1e-9))
        f = skfem.asm(traction, fb)
    clamp = basis.get_dofs(lambda x: x[0] < 1e-9)
    u = skfem.solve(*skfem.condense(K, f, D=clamp))
    return -u[load].mean(), basis, K, clamp


def skfem_frequency(mesh, basis, K, clamp, lumped=True):
    """The first eigenfrequency (Hz) of scikit-fem's K and mass M on the clamped mesh; ``lumped``:
    M's rows summed onto its diagonal, the mass the simulation uses."""
    @skfem.BilinearForm
    def mass(u, v, w):
        return rho * dot(u, v)
    M = skfem.asm(mass, basis)
    if lumped:
        M = sp.diags(np.asarray(M.sum(axis=1)).ravel()).tocsr()
    free = basis.complement_dofs(clamp)
    w2 = eigsh(K[free][:, free], k=1, M=M[free][:, free], sigma=0.0, which="LM")[0][0]
    return np.sqrt(w2) / (2 * np.pi)


def settle(mesh, frames, out=None):
    """The loaded, damped run to rest; returns the simulation and the states kept for ParaView."""
    sim = loaded_beam(mesh)
    kept = [sim.state.copy()]
    for state in sim.run(frames):
        if state.frame % 10 == 0:
            kept.append(state.copy())
    if out is not None:
        sa.io.write_series(os.path.join(out, "engineer_beam", "engineer_beam"), sim, states=kept)
    return sim


def released_frequency(mesh, state, frames):
    """Undamped, from the loaded rest state with the load removed: the frequency of the tip's swing."""
    sim = loaded_beam(mesh, load=False, damping=None)
    sim.state = sa.State(state.x.copy(), np.zeros_like(state.v))
    tip = tip_of(mesh)
    t, z = [0.0], [sim.state.x[tip, 2].mean() - b / 2]
    for s in sim.run(frames):
        t.append(s.time)
        z.append(s.x[tip, 2].mean() - b / 2)
    t, z = np.array(t), np.array(z)
    i = np.flatnonzero(np.sign(z[:-1]) != np.sign(z[1:]))  # zero crossings: half a period apart
    crossings = t[i] - z[i] * (t[i + 1] - t[i]) / (z[i + 1] - z[i])
    return 1.0 / (2.0 * np.mean(np.diff(crossings[:3])))


def root_stress(sim):
    """sigma_xx at the root's top fibre, fitted to alpha (L - x)(z - b/2) on 0.15 L <= x <= 0.5 L."""
    sigma = sim.stress().cauchy[:, 0, 0]
    rest = sim.system.p0[sim.system.t].mean(axis=0)  # the elements' centroids at rest (m, 3)
    g = (L - rest[:, 0]) * (rest[:, 2] - b / 2)
    band = (rest[:, 0] >= 0.15 * L) & (rest[:, 0] <= 0.5 * L)
    alpha = np.dot(sigma[band], g[band]) / np.dot(g[band], g[band])
    return alpha * L * b / 2


def trade(mesh, frames, budgets):
    """Affinification at each budget (relative to the response), stepped in turn with full space."""
    sims = {"full": loaded_beam(mesh)}
    for e in budgets:
        sims[e] = loaded_beam(mesh, sa.Affinification(target_error=e, relative_to="response", never_slower=False))
    full = sims["full"]
    worst = {e: [0.0, 0.0] for e in budgets}
    peak = {"response": 0.0, "stress": 0.0}

    def on_frame(frame, running):
        peak["response"] = max(peak["response"], metrics.response_amplitude(full.state.x, full.system.p0))
        sigma_ref = full.stress().cauchy
        peak["stress"] = max(peak["stress"], metrics.largest_stress(sigma_ref))
        for e in budgets:
            s = running[e]
            worst[e][0] = max(worst[e][0], metrics.distance_m(s.state.x, full.state.x))
            worst[e][1] = max(worst[e][1], metrics.stress_error(s.stress().cauchy, sigma_ref, 0.0))

    runs = runners.interleaved(sims, frames, on_frame=on_frame)
    return [{"budget": e, "response_error": worst[e][0] / peak["response"], "size_error": worst[e][0] / full.size,
             "error_m": worst[e][0], "stress_error": worst[e][1] / peak["stress"],
             "speedup": runs[e].summary["speedup"], "dof_ratio": runs[e].summary["dof_ratio"]} for e in budgets]


def main(resolution=2, frames=150, release_frames=70, budgets=(0.01, 0.05), out="out"):
    mesh, finer = beam_mesh(resolution), beam_mesh(resolution + 1)
    sim = settle(mesh, frames, out)
    tip = tip_of(mesh)
    deflection = -(sim.state.x[tip, 2].mean() - b / 2)
    static_p1, basis, K, clamp = skfem_static(mesh, skfem.ElementTetP1())
    static_p2 = skfem_static(mesh, skfem.ElementTetP2())[0]
    fine = settle(finer, frames)  # the same run one step finer: the discretisation error's trend
    deflection_fine = -(fine.state.x[tip_of(finer), 2].mean() - b / 2)
    f_sim = released_frequency(mesh, sim.state, release_frames)
    f_fe = skfem_frequency(mesh, basis, K, clamp)
    f_consistent = skfem_frequency(mesh, basis, K, clamp, lumped=False)
    sigma_root, sigma_fine = root_stress(sim), root_stress(fine)
    sigma_theory = P * L * (b / 2) / I
    rows = trade(mesh, frames, budgets)
    return dict(sim=sim, deflection=deflection, static_p1=static_p1, static_p2=static_p2,
                deflection_limit=richardson(deflection, deflection_fine, resolution), f_sim=f_sim, f_fe=f_fe,
                f_consistent=f_consistent, sigma_root=sigma_root,
                sigma_limit=richardson(sigma_root, sigma_fine, resolution), sigma_theory=sigma_theory, rows=rows,
                tets=mesh.t.shape[1], tets_fine=finer.t.shape[1])


def report(r):
    print(f"{r['tets']} linear tets ({r['tets_fine']} for the finer run); the tip load P = {P:g} N, at rest "
          f"after {r['sim'].state.time:.2f} s")
    print(f"static tip deflection: simulation at rest {1e3 * r['deflection']:.3f} mm, scikit-fem linear static "
          f"(same tets) {1e3 * r['static_p1']:.3f} mm ({100 * (r['deflection'] / r['static_p1'] - 1):+.2f} %)")
    print(f"  theory: Euler-Bernoulli {1e3 * delta_eb:.3f} mm, Timoshenko {1e3 * delta_timoshenko:.3f} mm; the "
          f"linear tets deflect {100 * (1 - r['deflection'] / delta_timoshenko):.0f} % less (locking); extrapolated "
          f"from two meshes {1e3 * r['deflection_limit']:.3f} mm ({100 * (r['deflection_limit'] / delta_timoshenko - 1):+.1f} %);"
          f"\n  quadratic tets on the same mesh (scikit-fem) {1e3 * r['static_p2']:.3f} mm "
          f"({100 * (r['static_p2'] / delta_timoshenko - 1):+.1f} %)")
    print(f"first bending frequency: simulation {r['f_sim']:.3f} Hz, scikit-fem eigenvalue on the same tets "
          f"{r['f_fe']:.3f} Hz with the lumped mass the simulation uses ({100 * (r['f_sim'] / r['f_fe'] - 1):+.1f} %), "
          f"{r['f_consistent']:.3f} Hz with the consistent mass;\n  Euler-Bernoulli {f_eb:.3f} Hz (locking again)")
    print(f"root stress (fitted, top fibre): {r['sigma_root'] / 1e3:.1f} kPa, extrapolated from two meshes "
          f"{r['sigma_limit'] / 1e3:.1f} kPa; M c / I = {r['sigma_theory'] / 1e3:.1f} kPa "
          f"({100 * (r['sigma_limit'] / r['sigma_theory'] - 1):+.1f} %)")
    print(f"{'budget':>7} {'resp err':>9} {'dist err':>9} {'dist m':>9} {'stress err':>10} {'DOF ratio':>9} "
          f"{'speedup':>8}")
    for row in r["rows"]:
        print(f"{row['budget']:7.3g} {row['response_error']:9.2e} {row['size_error']:9.2e} {row['error_m']:9.2e} "
              f"{row['stress_error']:10.2e} {row['dof_ratio']:9.3f} {row['speedup']:8.2f}")
    print("resp err = max vertex distance to the full-space run / its largest displacement from rest (the budget's "
          "unit);\ndist err = the same / the scene size; dist m = the same in metres; stress err = max element "
          "|sigma - sigma_ref| / max |sigma_ref|")


if __name__ in ("__main__", "example"):
    parser = argparse.ArgumentParser(description="A clamped beam under a tip load against theory and scikit-fem")
    parser.add_argument("--resolution", type=int, default=2, help="k: 3 k cells over the height (180 k^2 tets)")
    parser.add_argument("--out", default="out")
    args = parser.parse_args([] if __name__ == "example" else None)
    result = main(args.resolution, out=args.out)
    report(result)
    globals().update(result)
