"""Contact detection alone on the frames of a run: ``Detector.find`` timed on each frame's input.

A full-space run of ``--scene pile`` (the four soft boxes of ``benchmarks/budget.py``, ``--cells`` per box
edge) or of the paper's ``pills`` (eight copies of ``Pill.mesh`` from MESH_DIR, as in
``benchmarks/paper_table1.py``) steps to ``--end``; the detection inputs (positions, velocities, the
step's velocities) of the frames ``--start`` to ``--end - 1`` are kept and handed ``--repeat`` times to
a fresh detector (the candidate list built anew on the first frame), each call timed by wall and
CPU clock (``time.process_time``, which a loaded machine inflates less). Prints the median ms per
frame, the contacts of the last frame and how often the candidate list was built. One thread.
Usage::

    python benchmarks/detection_frames.py --scene pile --cells 4 --start 100 --end 120
    python benchmarks/detection_frames.py MESH_DIR --scene pills --start 44 --end 56
"""
import argparse
import os
import sys
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))  # measure the checkout this script sits in
sys.path.insert(0, HERE)
from skfem_affine.contact.geometry import Detector  # noqa: E402


def inputs(sim, start, end):
    """Step ``sim`` to frame ``end``; the detection inputs (x, v, h, w) of frames ``start`` to ``end - 1``."""
    det, seen, kept = sim.contact.detector, [0], []
    find = det.find

    def keep(x, v, dt, w=None):
        if start <= seen[0] < end:
            kept.append((x.copy(), v.copy(), dt, None if w is None else w.copy()))
        seen[0] += 1
        return find(x, v, dt, w)

    det.find = keep
    for _ in range(end):
        sim.step()
    det.find = find
    return kept


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh_dir", nargs="?", default=None, help="the paper's meshes (for --scene pills)")
    ap.add_argument("--scene", choices=["pile", "pills"], default="pile")
    ap.add_argument("--cells", type=int, default=4, help="cells per box edge (pile)")
    ap.add_argument("--start", type=int, required=True)
    ap.add_argument("--end", type=int, required=True)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    if not 0 <= args.start < args.end:
        raise ValueError(f"--start must be >= 0 and below --end, got {args.start} and {args.end}")
    if args.scene == "pile":
        from budget import pile
        sim = pile(args.cells)
    else:
        if args.mesh_dir is None:
            raise ValueError("--scene pills needs MESH_DIR (the paper's meshes)")
        import paper_table1
        sim = paper_table1.SCENES["pills"][2](args.mesh_dir, args.end)(None)
    frames = inputs(sim, args.start, args.end)
    d0, wall, cpu = sim.contact.detector, [], []
    for _ in range(args.repeat):
        det = Detector(sim.system, d0.colliders, d0.margin)
        for x, v, dt, w in frames:
            t0, c0 = time.perf_counter(), time.process_time()
            cs = det.find(x, v, dt, w)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
    out = {"wall_ms": 1e3 * float(np.median(wall)), "cpu_ms": 1e3 * float(np.median(cpu)),
           "contacts": 0 if cs is None else cs.size, "builds": det.builds, "frames": len(frames)}
    print(f"{args.scene}: detection {out['wall_ms']:.2f} ms wall, {out['cpu_ms']:.2f} ms CPU per frame (median "
          f"over {len(frames)} frames x {args.repeat}); {out['contacts']} contacts on the last frame; "
          f"candidate list built {out['builds']} times")
    return out


if __name__ == "__main__":
    main()
