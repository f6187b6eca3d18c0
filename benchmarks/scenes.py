"""Benchmark: time to generate N scenes of SIZE x SIZE into a RawStore with W worker processes.

    nice -n 5 python benchmarks/scenes.py [--n 480] [--size 1024] [--workers 2]

Prints wall time, CPU time and seconds per scene; the acceptance target is 480 scenes of
1024 x 1024 in under 120 s on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import tempfile
import time


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=480)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    from metraw.io.store import RawStore
    from metraw.scenes import generate

    tmp = tempfile.mkdtemp(prefix="metraw-scenes-bench-")
    try:
        t0 = time.perf_counter()
        c0 = time.process_time()
        with RawStore.create(os.path.join(tmp, "s.zarr")) as store:
            for img in generate(args.n, args.seed, size_px=args.size, workers=args.workers):
                store.append(img)
        wall = time.perf_counter() - t0
        cpu_main = time.process_time() - c0
        ch = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu_children = ch.ru_utime + ch.ru_stime
        load = os.getloadavg()[0]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    cpu = cpu_main + cpu_children
    print(f"{'scenes':>8} {'size':>6} {'workers':>7} {'wall_s':>8} {'cpu_s':>8} {'cpu_s/scene':>11} "
          f"{'est_wall_2cores_s':>17} {'load1':>6}")
    print(f"{args.n:>8} {args.size:>6} {args.workers:>7} {wall:>8.1f} {cpu:>8.1f} {cpu / args.n:>11.3f} "
          f"{cpu / 2:>17.1f} {load:>6.1f}")
    print(f"target: 480 scenes of 1024x1024 in < 120 s on 2 cores -> measured wall {wall:.1f} s for {args.n} scenes "
          f"({'met' if wall * 480 / args.n < 120 else 'not met'} at this machine load)")


if __name__ == "__main__":
    main()
