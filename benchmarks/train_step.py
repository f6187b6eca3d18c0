"""Where a training step's time goes: ``train_loop`` on pre-made batches, its variants, and torch.profiler's top ops.

    python benchmarks/train_step.py [--device cuda] [--steps 300] [--side 36]

The ``default`` profile's network (depth-2 U-Net, base 16, conditioned on the payload) and batches of 8 x 4 x side x
side (36: the pretraining box's typical packed crop), through ``metraw.segment.train.train_loop`` itself (seeded,
deterministic algorithms, precision ``auto``, the prefetch thread, the one-cycle schedule), so what it times is what
a training pays per step less the draws. Each variant runs ``steps`` steps after as many of warm-up and prints
milliseconds per step of wall and of process CPU time, and the step's arithmetic rate: the floating-point operations
of its convolutions and matrix products, forward and backward (counted once by ``torch.utils.flop_counter``), per
second of CPU time. Then the profiler's tables for 16 steps: by self device time and by self CPU time
(``cudaLaunchKernel`` counts the launches on a GPU).

Measured 2026-11-27 on one NVIDIA H100 (torch 2.11 + CUDA 13, 16 cores), 300 steps, side 36: as ``train_loop``
(bfloat16) 16.45 ms wall / 16.47 ms CPU; float32 13.36; not deterministic + cudnn.benchmark 14.62; no prefetch
thread 15.04. The profiler: 25.8 ms of kernels in 16 steps (1.6 ms a step), 12088 kernel launches (755 a step),
5622 ``fill_`` (deterministic mode initialises every new tensor). The GPU waits on the CPU that launches its
kernels: see docs/training.md, "GPUs". On the project's 2-core CPU (1 torch thread) the same loop takes ~22 ms a step.

Measured 2026-11-29 on the 2-core Intel Xeon VM (Emerald Rapids, ~2.3 GHz), 1 torch thread, side 36: a step is 1.53
GFLOP; float32 run as on an AVX2-only CPU (``ATEN_CPU_CAPABILITY=avx2 ONEDNN_MAX_CPU_ISA=AVX2``) 44.1 ms of CPU, 35
GFLOP/s, about half of what one core's two 8-wide float32 FMA units give at 2.3 GHz (74 GFLOP/s); with AVX-512 34.8
ms, 44 GFLOP/s. The step is bound by its arithmetic: no faster implementation of the same network on the same core
buys more than ~2x (docs/benchmarks.md, the main job on an AVX2 CPU).
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--steps", type=int, default=300, help="timed steps per variant (after as many of warm-up)")
    ap.add_argument("--side", type=int, default=36, help="packed crop side, pixels")
    args = ap.parse_args()

    import torch
    from torch.profiler import ProfilerActivity, profile

    import metraw.segment.train as train
    from metraw.segment.condition import CONDITION_FEATURES
    from metraw.segment.train import TrainConfig, build_model, set_determinism, train_loop

    from torch.utils.flop_counter import FlopCounterMode

    dev, n = args.device, args.steps
    base = TrainConfig(epochs=1, learning_rate=8e-3, batch_size=8, crop_px=64, base_channels=16, depth=2,
                       condition=True, precision="auto", threads=1, seed=0)
    rng = np.random.default_rng(0)
    shape = (8, 4, args.side, args.side)
    batches = [(rng.normal(size=shape).astype(np.float32), rng.uniform(size=shape).astype(np.float32),
                rng.normal(size=(8, len(CONDITION_FEATURES))).astype(np.float32)) for _ in range(16)]

    def sync():
        if dev != "cpu":
            torch.cuda.synchronize()

    def run(label: str, deterministic: bool = True, **config) -> None:
        cfg = TrainConfig(**{**base.__dict__, **config})
        set_determinism(0, 1, dev)
        if not deterministic:
            torch.use_deterministic_algorithms(False)
            torch.backends.cudnn.benchmark = True
        model = build_model(4, cfg, 1, 1).to(dev)

        def epoch(_):
            return (batches[i % len(batches)] for i in range(n))

        train_loop(model, epoch, n, cfg, dev, False)  # warm-up: kernels, caches, allocator
        sync()
        wall, cpu = time.perf_counter(), time.process_time()
        train_loop(model, epoch, n, cfg, dev, False)
        sync()
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        print(f"{label:<46} {1e3 * wall / n:8.2f} ms/step wall {1e3 * cpu / n:8.2f} ms CPU"
              f" {step_flops * n / cpu / 1e9:7.1f} GFLOP/s of CPU time", flush=True)

    set_determinism(0, 1, dev)
    with FlopCounterMode(display=False) as counter:
        train_loop(build_model(4, base, 1, 1).to(dev), lambda _: iter(batches[:1]), 1, base, dev, False)
    step_flops = counter.get_total_flops()

    print(f"torch {torch.__version__}, device {dev}"
          + (f" ({torch.cuda.get_device_name(0)})" if dev != "cpu" else "") + f", {n} steps, batches {shape}; "
          f"CPU capability {torch.backends.cpu.get_cpu_capability()}; a step {step_flops / 1e9:.3f} GFLOP "
          "(convolutions and matrix products, forward and backward)")
    run("as train_loop (precision auto, deterministic)")
    run("float32", precision="float32")
    run("not deterministic, cudnn.benchmark", deterministic=False)
    prefetch = train.PREFETCH_BATCHES
    train.PREFETCH_BATCHES = 0
    run("no prefetch thread")
    train.PREFETCH_BATCHES = prefetch

    set_determinism(0, 1, dev)
    model = build_model(4, base, 1, 1).to(dev)
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if dev != "cpu" else [])
    with profile(activities=activities) as prof:
        train_loop(model, lambda _: iter(batches), len(batches), base, dev, False)
        sync()
    table = prof.key_averages()
    if dev != "cpu":
        print(table.table(sort_by="self_cuda_time_total", row_limit=12, max_name_column_width=40))
    print(table.table(sort_by="self_cpu_time_total", row_limit=12, max_name_column_width=40))


if __name__ == "__main__":
    main()
