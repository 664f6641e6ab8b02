"""Contact detection with the candidate list (pairs between bodies kept over frames within a skin)
against a search from scratch, on the same frames, timed in turn in one process.

A simulation of ``--scene pile`` (the four soft boxes of ``benchmarks/budget.py``, ``--cells`` per box
edge, at the thresholds of ``benchmarks/contact_phases.py``) or ``--scene pills`` (``--pills`` procedural
capsules dropped into a bowl, falling and colliding) is stepped with ``--method``; each frame's
detection input (positions, velocities, the step's) is handed to two detectors, one with the
list (default skin) and one without (skin 0), in alternating order, each timed, their contacts
compared field by field (any difference stops the run). Reports, over the frames ``--start`` to
``--end - 1``: ms per frame of each, the ratio, the contacts and how often the list was built.
Usage::

    python benchmarks/detection_list.py --cells 4 --start 100 --end 120
    python benchmarks/detection_list.py --scene pills --pills 8 --start 0 --end 60 --method full
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
import contact_phases  # noqa: E402
import skfem_affine as sa  # noqa: E402
from skfem_affine.contact.geometry import Detector  # noqa: E402

FIELDS = ("vertex", "others", "weights", "normal", "distance", "key", "own")


def same(cs, ref):
    """Whether two contact sets (or None) are equal, field by field, exactly."""
    if cs is None or ref is None:
        return cs is None and ref is None
    return all((getattr(cs, f) is None and getattr(ref, f) is None)
               or np.array_equal(getattr(cs, f), getattr(ref, f)) for f in FIELDS)


def run(cells, method, start, end, scene="pile", pills=8):
    """ms per frame of detection with the list and from scratch, contacts and list builds, over
    the frames ``start`` to ``end - 1``."""
    if scene == "pills":
        reducer = {"full": None, "affinification": sa.Affinification(tau_a=1e-4, tau_e=2e-4),
                   "rigidification": sa.Rigidification(tau_r=1e-4, tau_e=2e-4)}[method]
        sim = sa.scenes.pills(n=pills, reducer=reducer)
    else:
        sim = contact_phases.builders(None, "pile", end, cells)[contact_phases.METHODS.index(method)]
    own = sim.contact.detector
    listed, scratch = (Detector(sim.system, own.colliders, own.margin, skin=s) for s in (None, 0.0))
    times, contacts, frame = {"list": [], "scratch": []}, [], [0]
    find = own.find

    def both(x, v, dt, w=None):
        pair = [("list", listed), ("scratch", scratch)][::1 if frame[0] % 2 else -1]
        found = {}
        for name, det in pair:
            t0 = time.perf_counter()
            found[name] = det.find(x, v, dt, w)
            if frame[0] >= start:
                times[name].append(time.perf_counter() - t0)
        if not same(found["list"], found["scratch"]):
            raise RuntimeError(f"frame {frame[0]}: the list's contacts differ from a search from scratch")
        if frame[0] >= start:
            contacts.append(0 if found["list"] is None else found["list"].size)
        builds.append(listed.builds)
        return find(x, v, dt, w)

    builds = []
    own.find = both
    for frame[0] in range(end):
        sim.step()
    lst, scr = (1e3 * np.mean(times[k]) for k in ("list", "scratch"))
    return {"list_ms": lst, "scratch_ms": scr, "ratio": lst / scr, "contacts": float(np.mean(contacts)),
            "builds": builds[-1] - builds[start - 1] if start else builds[-1]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=["pile", "pills"], default="pile")
    ap.add_argument("--cells", type=int, default=4, help="cells per box edge of the pile")
    ap.add_argument("--pills", type=int, default=8, help="capsules in the bowl")
    ap.add_argument("--method", choices=contact_phases.METHODS, default="affinification")
    ap.add_argument("--start", type=int, default=100)
    ap.add_argument("--end", type=int, default=120)
    args = ap.parse_args(argv)
    out = run(args.cells, args.method, args.start, args.end, args.scene, args.pills)
    what = f"pile {args.cells} cells" if args.scene == "pile" else f"{args.pills} pills"
    print(f"{what}, {args.method}, frames {args.start}-{args.end - 1}: detection "
          f"{out['list_ms']:.2f} ms with the list, {out['scratch_ms']:.2f} from scratch (ratio {out['ratio']:.2f}), "
          f"{out['contacts']:.0f} contacts, list built {out['builds']} times")
    return out


if __name__ == "__main__":
    main()
