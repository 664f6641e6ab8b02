"""Command line: ``python -m skfem_affine demo`` (also installed as ``skfem-affine``)."""
import argparse
import os
import sys
import time

from . import io, scenes


def demo(args):
    """Run the cantilever beam, print progress and frames/s, write a ParaView series."""
    sim = scenes.cantilever(resolution=args.resolution)
    frames = args.frames if args.frames is not None else sim.frames
    print(f"cantilever: {sim.system.m} tets, {sim.system.n} vertices, {sim.system.free.size} free DOFs, "
          f"dt = {sim.dt} s, {frames} frames, solver = {type(sim.solver).__name__}")
    writer = io.SeriesWriter(os.path.join(args.out, "cantilever"))
    writer.write(sim, sim.state)
    tip = sim.system.p0[:, 0] > sim.system.p0[:, 0].max() - 1e-9
    t0 = time.perf_counter()
    for state in sim.run(frames):
        if state.frame % args.every == 0 or state.frame == frames:
            writer.write(sim, state)
        if state.frame % 50 == 0 or state.frame == frames:
            rate = state.frame / (time.perf_counter() - t0)
            print(f"  frame {state.frame:4d}  t = {state.time:5.2f} s  tip z = {state.x[tip, 2].mean():+.3f} m  "
                  f"({rate:.1f} frames/s)", flush=True)
    summary = sim.stats.summary()
    phases = ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in summary.items() if k.endswith("_s") and k not in ("wall_s", "frames_per_s"))
    print(f"done: {frames} frames in {summary['wall_s']:.2f} s = {summary['frames_per_s']:.1f} frames/s ({phases})")
    print(f"wrote {writer.pvd} ({len(writer.entries)} frames; open it in ParaView)")
    return 0


def main(argv=None):
    parser = argparse.ArgumentParser(prog="skfem-affine", description="Fast adaptive elastodynamics for scikit-fem.")
    sub = parser.add_subparsers(dest="command")
    p = sub.add_parser("demo", help="simulate the cantilever beam and write a ParaView series")
    p.add_argument("--resolution", type=int, default=6, help="cells across the beam: 24 k^3 tets (default 6)")
    p.add_argument("--frames", type=int, default=None, help="frames to simulate (default: the scene's 370)")
    p.add_argument("--every", type=int, default=10, help="write every N-th frame (default 10)")
    p.add_argument("--out", default="out", help="output folder (default ./out)")
    p.set_defaults(func=demo)
    args = parser.parse_args(argv)
    if args.command is None:
        args = parser.parse_args(["demo"] + (argv if argv is not None else sys.argv[1:]))
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
