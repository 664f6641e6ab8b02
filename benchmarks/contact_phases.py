"""Where a contact frame's time goes: per-phase means over a window of frames, full / affinification /
rigidification stepped in turn in one process, on the paper's contact scenes.

The scenes are those of ``benchmarks/paper_table1.py`` (the paper's meshes, read from MESH_DIR, and
its thresholds). Every method runs from frame 0; the frames ``--start`` to ``--end`` are recorded:
the frame's wall time, the factorisation, the Delassus operator, the PGS solve (with the velocity
and position corrections), detection (the rest of contact), the contacts and the DOFs solved.
The order of the methods rotates from frame to frame. Usage::

    python benchmarks/contact_phases.py MESH_DIR --scene wheel --start 145 --end 160
"""
import argparse
import json
import os
import sys
import time

# one BLAS/MKL thread for every method (read before numpy loads them)
THREADS = sys.argv[sys.argv.index("--threads") + 1] if "--threads" in sys.argv else "1"
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, THREADS)

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))  # measure the checkout this script sits in
sys.path.insert(0, HERE)
import paper_table1  # noqa: E402

METHODS = ("full", "affinification", "rigidification")
COLUMNS = ("wall", "factorization", "delassus", "pgs", "detection", "contact", "n_contacts", "pgs_iterations", "dofs")


def record(rec):
    """The columns of one frame's record (times in ms)."""
    out = {k: 1e3 * float(rec.get(k, 0.0)) for k in ("wall", "factorization", "delassus", "pgs", "contact")}
    out["detection"] = out["contact"] - out["delassus"] - out["pgs"]
    out.update(n_contacts=float(rec.get("n_contacts", 0)), pgs_iterations=float(rec.get("pgs_iterations", 0)),
               dofs=float(rec.get("dofs", 0)))
    return out


def run(mesh_dir, scene, start, end):
    row, _, factory, fraction = paper_table1.SCENES[scene]
    build = factory(mesh_dir, end)
    sims = [build(None)] + [build(r) for r in paper_table1.reducers(row, fraction)]
    rows = {m: [] for m in METHODS}
    t0 = time.perf_counter()
    for frame in range(end):
        turn = [(frame + i) % len(sims) for i in range(len(sims))]  # rotate who steps first
        for i in turn:
            sims[i].step()
            if frame >= start:
                rows[METHODS[i]].append(record(sims[i].stats[-1]))
        if frame % 10 == 0:
            print(f"{scene} frame {frame}/{end} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    return {m: {c: float(np.mean([r[c] for r in rs])) for c in COLUMNS} for m, rs in rows.items()}


def markdown(scene, means):
    lines = [f"| {scene} | " + " | ".join(METHODS) + " |", "|---|---|---|---|"]
    for c in COLUMNS:
        lines.append(f"| {c} | " + " | ".join(f"{means[m][c]:.0f}" for m in METHODS) + " |")
    share = [means[m]["contact"] / max(means[m]["wall"], 1e-300) for m in METHODS]
    lines.append("| contact share of the frame | " + " | ".join(f"{100 * s:.0f} %" for s in share) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh_dir")
    ap.add_argument("--scene", choices=["wheel", "octopus", "pills"], required=True)
    ap.add_argument("--start", type=int, required=True)
    ap.add_argument("--end", type=int, required=True)
    ap.add_argument("--threads", default="1", help="BLAS/MKL threads (read before numpy is imported)")
    ap.add_argument("--json", default=None, help="also write the means here")
    args = ap.parse_args(argv)
    means = run(args.mesh_dir, args.scene, args.start, args.end)
    print(f"frames {args.start}-{args.end - 1}, ms per frame (means)")
    print(markdown(args.scene, means))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"scene": args.scene, "start": args.start, "end": args.end, "means": means}, f, indent=1)


if __name__ == "__main__":
    main()
