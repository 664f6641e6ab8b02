"""Resident memory of a long contact run: does it stop growing once the run is under way?

Steps the procedural pills (or another contact scene) in full space, with affinification and with
rigidification, in turn in one process, and prints the process's resident size (VmRSS) every
``--every`` frames, and its growth from frame ``--after`` to the end. Usage::

    python benchmarks/contact_memory.py --scene pills --frames 600 --after 100
"""
import argparse
import os
import sys

# one BLAS/MKL thread, as the other contact benchmarks (read before numpy loads them)
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # this checkout
import skfem_affine as sa  # noqa: E402


def resident_mib():
    """The process's resident set size (MiB), from /proc/self/status."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS in /proc/self/status (Linux only)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="pills", choices=["pills", "bowling", "stacked_beams"])
    ap.add_argument("--resolution", type=int, default=1)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--after", type=int, default=100, help="growth is measured from this frame to the end")
    ap.add_argument("--every", type=int, default=50)
    args = ap.parse_args(argv)
    build = sa.scenes.SCENES[args.scene]
    sims = [build(resolution=args.resolution, reducer=r)
            for r in (None, sa.Affinification(tau_a=1.0, tau_e=2.0), sa.Rigidification(tau_r=0.05))]
    base = None
    for frame in range(1, args.frames + 1):
        for sim in sims:
            sim.step()
        if frame == args.after:
            base = resident_mib()
        if frame % args.every == 0 or frame == args.frames:
            contacts = [sim.stats[-1].get("n_contacts", 0) for sim in sims]
            print(f"frame {frame}: resident {resident_mib():.1f} MiB, contacts {contacts}", flush=True)
    end = resident_mib()
    print(f"resident at frame {args.after}: {base:.1f} MiB, at frame {args.frames}: {end:.1f} MiB, "
          f"growth {100 * (end / base - 1):+.1f} %")


if __name__ == "__main__":
    main()
