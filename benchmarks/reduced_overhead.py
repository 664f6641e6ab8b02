"""What a reduced frame costs beyond full space: full space, affinification (or rigidification) on the
old route and on the new one, stepped in turn in one process, per-phase means over a window of frames.

The old route factorises the whole reduced matrix A_r in the compact numbering (elastic DOFs, then
the bodies' columns); the new one numbers the unknowns as full space does in scenes of several bodies
and factorises each body's block on its own (only the bodies whose clusters changed are analysed
again), and, in a scene of one body, solves a frame whose A_r pattern is new and that reduces few DOFs
through the full A's factorisation (``skfem_affine.reducers.affine.constrained``). Both give the same
frames to round-off. The scenes are those of ``benchmarks/paper_table1.py`` (the paper's meshes in
MESH_DIR, its thresholds) and ``pile``, the four soft boxes of ``benchmarks/budget.py`` at tau_a = 1e-4
(no MESH_DIR). Every run starts from a checkpoint at ``--start`` in ``--checkpoints``
(``SCENE_full_START.npz``, ``SCENE_METHOD_START.npz``), written there first when missing (the runs to
it are not interleaved, and take minutes on the pills). Usage::

    python benchmarks/reduced_overhead.py MESH_DIR --scene pills --start 100 --frames 10 --checkpoints RUNS
    python benchmarks/reduced_overhead.py MESH_DIR --scene wheel --start 145 --frames 6 --checkpoints RUNS
    python benchmarks/reduced_overhead.py MESH_DIR --scene octopus --start 72 --frames 6 --checkpoints RUNS
    python benchmarks/reduced_overhead.py --scene pile --cells 2 --start 60 --frames 10 --checkpoints RUNS
    python benchmarks/reduced_overhead.py MESH_DIR --scene pills --start 100 --checkpoints RUNS --factorisations

``--factorisations`` times instead the factorisations of the frame after ``--start`` in isolation (the
least of 5 runs: robust to load): A_r whole with and without its analysis, the full A, and A_r per
scene body with and without the analysis of the bodies holding clusters.
"""
import argparse
import os
import sys
import time

# one BLAS/MKL thread for every method (read before numpy loads them)
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))  # measure the checkout this script sits in
sys.path.insert(0, HERE)
import paper_table1  # noqa: E402
import skfem_affine as sa  # noqa: E402

PHASES = ("wall", "assembly", "prediction", "clustering", "map_assembly", "reduced_assembly", "factorization",
          "solve", "delassus", "pgs", "contact")
COUNTS = ("dofs", "n_clusters", "n_contacts")


def old_route(sim):
    """The simulation's reducer on the old route: the whole A_r, compact numbering."""
    reducer = sim.integrator.reducer
    reducer.full_numbering, reducer.blocks, reducer.constraints_max = False, None, -1
    return sim


def started(build, reducer, path, start):
    """A simulation at frame ``start``: loaded from ``path``, else run there from frame 0 and saved."""
    sim = build(reducer)
    if os.path.isfile(path):
        sim.load_state(path)
    else:
        for _ in range(start):
            sim.step()
        sim.save(path)
    return sim


def run(mesh_dir, scene, start, frames, checkpoints, method="affinification", warmup=2, cells=2):
    """Per-phase means (ms, and the mean counts) of full space, ``method`` on the old route and on the
    new one over ``frames`` frames after ``warmup`` more from ``start`` (a resumed run's first frames
    analyse its systems anew), stepped in turn (the order rotating); and the largest position
    difference between the two routes (m)."""
    which = 0 if method == "affinification" else 1
    if scene == "pile":  # four soft boxes settling on the ground (benchmarks/budget.py), no meshes
        from budget import pile

        def build(reducer):
            return pile(cells, reducer)

        def reducer():
            return (sa.Affinification(tau_a=1e-4, tau_e=2e-4), sa.Rigidification(tau_r=1e-4, tau_e=2e-4))[which]
    else:
        if mesh_dir is None:
            raise ValueError(f"--scene {scene} needs MESH_DIR (the paper's meshes)")
        row, _, factory, fraction = paper_table1.SCENES[scene]
        build = factory(mesh_dir, start + warmup + frames)

        def reducer():
            return paper_table1.reducers(row, fraction)[which]

    os.makedirs(checkpoints, exist_ok=True)
    path = os.path.join(checkpoints, f"{scene}_{{}}_{start}.npz")
    sims = {"full": started(build, None, path.format("full"), start),
            "old route": old_route(started(build, reducer(), path.format(method), start)),
            "new route": started(build, reducer(), path.format(method), start)}
    names = list(sims)
    t0 = time.perf_counter()
    for frame in range(warmup + frames):
        for i in range(len(names)):
            sims[names[(frame + i) % len(names)]].step()
        print(f"{scene} frame {start + frame + 1} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    means = {}
    for name, sim in sims.items():
        recs = sim.stats[-frames:]
        means[name] = {k: 1e3 * float(np.mean([r.get(k, 0.0) for r in recs])) for k in PHASES}
        means[name].update({k: float(np.mean([r.get(k, 0) for r in recs])) for k in COUNTS})
        means[name]["other"] = means[name]["wall"] - means[name]["factorization"] - means[name]["contact"]
        means[name]["wall (median)"] = 1e3 * float(np.median([r["wall"] for r in recs]))
    gap = float(np.abs(sims["old route"].state.x - sims["new route"].state.x).max())
    return means, gap


def factorisations(mesh_dir, scene, start, checkpoints, method="affinification", repeat=5, cells=2):
    """The least of ``repeat`` timings (ms) of factorising the frame after the checkpoint at ``start``:
    A_r whole with a new analysis, A_r whole numeric only, the full A numeric only, A_r per scene body
    numeric only, and per body with the bodies holding clusters analysed anew (the frame of a new
    pattern on the new route)."""
    from skfem_affine.reducers.affine import blocks
    from skfem_affine.reducers.affine.mapping import reduced_matrix
    from skfem_affine.reducers.affine.numbering import FullNumbering
    from skfem_affine.solvers import Pardiso
    seen = {}
    which = 0 if method == "affinification" else 1
    if scene == "pile":
        from budget import pile
        sim = started(lambda r: pile(cells, r), (sa.Affinification(tau_a=1e-4, tau_e=2e-4),
                                                 sa.Rigidification(tau_r=1e-4, tau_e=2e-4))[which],
                      os.path.join(checkpoints, f"{scene}_{method}_{start}.npz"), start)
    else:
        row, _, factory, fraction = paper_table1.SCENES[scene]
        sim = started(factory(mesh_dir, start + 1), paper_table1.reducers(row, fraction)[which],
                      os.path.join(checkpoints, f"{scene}_{method}_{start}.npz"), start)
    reducer = sim.integrator.reducer
    original = reducer.solve

    def spy(problem):
        seen["problem"], seen["result"] = problem, original(problem)
        return seen["result"]

    reducer.solve = spy
    sim.step()
    problem, gmap = seen["problem"], seen["result"].mapping
    if gmap is None or not gmap.n_bodies:
        raise ValueError(f"frame {start + 1} of the {scene} reduces nothing")
    Ar = reduced_matrix(sim.model, problem.data, gmap, upper=True)
    order = gmap.elimination_order(reducer.vertex_rank)
    num = FullNumbering(gmap, sim.model.coefficients[0] * reducer.mdiag)
    W, ow = num.matrix(Ar), num.order(order)
    labels = blocks.unknown_labels(sim.contact.bodies, num, gmap.width)
    changed = np.unique(labels[num.columns[gmap.n_elastic:]])
    A = problem.matrix()
    whole, full, per_body = Pardiso(), Pardiso(), blocks.BodyBlocks()
    whole.factorize(Ar, upper=True, order=order)
    full.factorize(A)
    per_body.factorize(W, labels, ow)

    def fresh():
        s = Pardiso()
        s._analysed = True  # a later analysis, as a run's
        s.factorize(Ar, upper=True, order=order)

    def changed_bodies():
        for b in changed:
            per_body.handles.pop(int(b), None)
        per_body.factorize(W, labels, ow)

    cases = {"A_r whole, analysis and factorisation": fresh,
             "A_r whole, factorisation": lambda: whole.factorize(Ar, upper=True, order=order),
             "full A, factorisation": lambda: full.factorize(A),
             "A_r per body, factorisation": lambda: per_body.factorize(W, labels, ow),
             f"A_r per body, {changed.size} bodies analysed": changed_bodies}
    out = {}
    for name, case in cases.items():
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            case()
            times.append(time.perf_counter() - t0)
        out[name] = 1e3 * min(times)
    return out


def markdown(scene, means):
    names = list(means)
    lines = [f"| {scene} | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for key in ("wall (median)",) + PHASES + ("other",) + COUNTS:
        lines.append(f"| {key} | " + " | ".join(f"{means[n][key]:.0f}" for n in names) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh_dir", nargs="?", default=None, help="the paper's meshes (not for --scene pile)")
    ap.add_argument("--scene", choices=["pills", "wheel", "octopus", "pile"], required=True)
    ap.add_argument("--cells", type=int, default=2, help="cells per box edge of the pile")
    ap.add_argument("--method", choices=["affinification", "rigidification"], default="affinification")
    ap.add_argument("--start", type=int, required=True)
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--warmup", type=int, default=2, help="frames stepped before the window")
    ap.add_argument("--checkpoints", required=True, help="folder of the checkpoints at --start")
    ap.add_argument("--factorisations", action="store_true",
                    help="instead, time the factorisations of the frame after --start (least of 5)")
    args = ap.parse_args(argv)
    if args.factorisations:
        times = factorisations(args.mesh_dir, args.scene, args.start, args.checkpoints, args.method, cells=args.cells)
        print(f"frame {args.start + 1}, least of 5, ms")
        print("\n".join(f"| {name} | {ms:.0f} |" for name, ms in times.items()))
        return times
    means, gap = run(args.mesh_dir, args.scene, args.start, args.frames, args.checkpoints, args.method,
                    args.warmup, args.cells)
    first = args.start + args.warmup + 1
    print(f"frames {first}-{first + args.frames - 1}, ms per frame (means); largest position difference "
          f"between the routes {gap:.1e} m")
    print(markdown(args.scene, means))
    return means, gap


if __name__ == "__main__":
    main()
