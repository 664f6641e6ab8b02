"""What keeps resting pills elastic under affinification at the paper's thresholds (tau_a 1e-5, tau_e 1e-4).

Per frame it prints what the clustering compares with the thresholds: the largest difference of an
element's deformation rate to a face neighbour's (1/s), from the current velocities for elements that
were elastic (against tau_a) and from the oracle's predicted ones for elements that were affine
(against tau_e), per material, with the vertex speeds and the fraction of elements made affine.

Two scenes:

* ``--scene small``: two procedural pills (192 tets) dropped into the bowl, ``--frames`` frames,
  reported from ``--start`` on (they lie still, |v| below 1e-8 m/s, from about frame 400);
* ``--scene paper``: the paper's pills (eight copies of Pill.mesh, ``benchmarks/paper_table1.py``)
  resumed from an affinification checkpoint of that benchmark (``--checkpoint``), a few frames.

``--paper-oracle`` predicts as the paper (one PCG step from zero) instead of from the bodies' mean
response, for comparison. ``--interleave FULL_CHECKPOINT`` (``--scene paper``) steps, in turn, full
space from its checkpoint and affinification from ``--checkpoint`` with either oracle, and reports
their mean frame times and DOFs::

    python benchmarks/resting_pills.py --scene small --frames 500 --start 400
    python benchmarks/resting_pills.py --scene small --frames 500 --start 400 --paper-oracle
    python benchmarks/resting_pills.py MESH_DIR --scene paper --checkpoint RUNS/affinification-000400.npz --frames 6
    python benchmarks/resting_pills.py MESH_DIR --scene paper --checkpoint RUNS/affinification-000400.npz \
        --interleave RUNS/full-000400.npz --frames 6
"""
import argparse
import os
import sys
import time

import numpy as np

import skfem_affine as sa
from skfem_affine.reducers.affine import clustering, oracle

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
TAU_A, TAU_E = 1e-5, 1e-4


def _rate_spread(reducer, system, v):
    """Per element, the largest Frobenius distance of its deformation rate to a face neighbour's."""
    indptr, indices = reducer.adjacency
    F = np.ascontiguousarray(system.deformation_gradients(v).reshape(-1, 9))
    return clustering._worst_neighbour_difference(indptr.astype(np.int64), indices.astype(np.int64), F)


def instrument(reducer, rows):
    """Wrap the reducer's clustering to record, per frame, the measure each element is judged on."""
    labels_of = reducer._labels

    def labels(problem, v_pred):
        sysm = problem.system
        was = reducer.was_reduced.copy()
        seen = np.where(was, _rate_spread(reducer, sysm, v_pred), _rate_spread(reducer, sysm, problem.v))
        body = np.repeat(np.arange(len(sysm.bodies)), np.diff(sysm.vertex_offsets))[sysm.t[0]]
        out = labels_of(problem, v_pred)
        speed = np.linalg.norm(problem.v, axis=1)
        rows.append({"affine": float(np.mean(out >= 0)), "seen": float(np.median(seen)),
                     "even": float(np.median(seen[body % 2 == 0])), "odd": float(np.median(seen[body % 2 == 1])),
                     "pred_on_affine": float(np.median(seen[was])) if was.any() else float("nan"),
                     "v_median": float(np.median(speed)), "v_max": float(speed.max())})
        return out
    reducer._labels = labels


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mesh_dir", nargs="?", default=os.environ.get("SKFEM_AFFINE_MESHES"))
    ap.add_argument("--scene", choices=["small", "paper"], default="small")
    ap.add_argument("--checkpoint", help="an affinification checkpoint of benchmarks/paper_table1.py (--scene paper)")
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--start", type=int, default=0, help="first frame reported")
    ap.add_argument("--paper-oracle", action="store_true", help="one PCG step from zero, as the paper")
    ap.add_argument("--interleave", metavar="FULL_CHECKPOINT", help="full space's checkpoint of the same run")
    args = ap.parse_args(argv)
    if args.interleave:
        return interleave(args)
    if args.paper_oracle:
        oracle.coarse_guess = lambda *a: None  # predict() then starts from zero
    reducer = sa.Affinification(TAU_A, TAU_E)
    if args.scene == "small":
        sim = sa.scenes.pills(n=2, resolution=1, reducer=reducer)
    else:
        if not (args.mesh_dir and args.checkpoint):
            ap.error("--scene paper needs MESH_DIR (or SKFEM_AFFINE_MESHES) and --checkpoint")
        import paper_table1
        sim = paper_table1.pills(args.mesh_dir)(reducer)
        sim.load_state(args.checkpoint)
    rows = []
    instrument(reducer, rows)
    print("frame  affine  measure(median)  even/odd bodies  predicted on affine  |v| median  |v| max  DOFs  prediction s  wall s")
    first = sim.state.frame
    for k in range(args.frames):
        t0 = time.perf_counter()
        sim.step()
        wall = time.perf_counter() - t0
        frame = first + k + 1
        if frame >= args.start:
            r = rows[-1]
            print(f"{frame:5d}  {r['affine']:.3f}  {r['seen']:.2e}  {r['even']:.2e}/{r['odd']:.2e}  "
                  f"{r['pred_on_affine']:.2e}  {r['v_median']:.2e}  {r['v_max']:.2e}  {sim.stats[-1]['dofs']}  {sim.stats[-1].get('prediction', 0.0):.3f}  {wall:.2f}",
                  flush=True)


def interleave(args):
    """Full space and affinification with the mean-response and the paper's oracle, stepped in turn."""
    import paper_table1
    build = paper_table1.pills(args.mesh_dir)
    sims = {"full": build(None)}
    sims["full"].load_state(args.interleave)
    for name in ("mean-response oracle", "paper's oracle"):
        sims[name] = build(sa.Affinification(TAU_A, TAU_E))
        sims[name].load_state(args.checkpoint)
    guess, names, wall = oracle.coarse_guess, list(sims), {k: [] for k in sims}
    for k in range(args.frames):
        for name in names[k % 3:] + names[:k % 3]:  # the order rotates, so that load slows each alike
            oracle.coarse_guess = (lambda *a: None) if name == "paper's oracle" else guess
            t0 = time.perf_counter()
            sims[name].step()
            wall[name].append(time.perf_counter() - t0)
        print(sims["full"].state.frame, {name: (round(wall[name][-1], 2), sims[name].stats[-1]["dofs"]) for name in names},
              flush=True)
    oracle.coarse_guess = guess
    full = np.mean(wall["full"])
    for name in names[1:]:
        dofs = np.mean([r["dofs"] for r in sims[name].stats[-args.frames:]]) / sims["full"].stats[-1]["dofs"]
        print(f"{name}: speed vs full {full / np.mean(wall[name]):.2f}, DOF ratio {dofs:.3f}")
    x = [sims[name].state.x for name in names[1:]]
    print(f"the two oracles' largest vertex distance: {np.linalg.norm(x[0] - x[1], axis=1).max() / sims['full'].model.size:.1e}"
          " of the scene's size")


if __name__ == "__main__":
    main()
