"""How fast the command line answers ``--help``: wall time of ``skfem-affine [COMMAND] --help``.

Each command runs as a fresh process (``python -m skfem_affine ... --help``), the commands in
turn, ``--repeat`` rounds; the first round warms the disk cache and is dropped. Prints the median
and the largest wall time per command, and what a bare ``python -c pass`` costs on this machine
for scale. The target is under 1 s for every command on a warm install. Usage::

    python benchmarks/cli_startup.py [--repeat 5]
"""
import argparse
import os
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COMMANDS = ([], ["demo"], ["run"], ["compare"], ["sweep"], ["budget"], ["scaling"], ["scenes"])


def wall(argv):
    """Seconds one process ``argv`` takes, start to exit."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    t0 = time.perf_counter()
    subprocess.run(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    return time.perf_counter() - t0


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=5, help="rounds after the warm-up one (default 5)")
    args = parser.parse_args()
    runs = {"python -c pass": [sys.executable, "-c", "pass"]}
    runs.update({"skfem-affine " + " ".join(c + ["--help"]): [sys.executable, "-m", "skfem_affine", *c, "--help"]
                 for c in COMMANDS})
    times = {name: [] for name in runs}
    for round_ in range(args.repeat + 1):
        for name, argv in runs.items():  # commands in turn, so that machine load hits all alike
            t = wall(argv)
            if round_:
                times[name].append(t)
    print(f"{'command':<34} {'median s':>9} {'max s':>7}")
    for name, ts in times.items():
        print(f"{name:<34} {statistics.median(ts):9.3f} {max(ts):7.3f}")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"{args.repeat} rounds; {os.cpu_count()} cores, load average {load:.1f}")
    slowest = max(max(ts) for name, ts in times.items() if name.startswith("skfem-affine"))
    return 0 if slowest < 1.0 else 1


if __name__ == "__main__":
    sys.exit(main())
