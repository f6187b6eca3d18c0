"""Training-step time of the segmenter in float32 against bfloat16 autocast, and what ``precision: auto`` picks here.

    python benchmarks/precision.py [--rounds 21] [--threads 1] [--device cpu]

One step = forward, loss, backward and optimiser step of a batch of 8 (the training loop's arithmetic and
optimiser, ``metraw.segment.train.train_loop`` / ``make_optimizer``), on random inputs of the shapes the profiles train on:
- ``default``: depth-2 U-Net, base 16, conditioned on 6 payload values, 34 px packed crops (a nominal satellite
  image) and 64 px (the crop side);
- ``source``: depth-3 U-Net, base 16, 64 px crops (the drone reference).
The two precisions alternate step by step (machine noise falls on both); each row gives the median of
``rounds`` steps after 3 warm-ups, and the ratio float32 / bfloat16 (> 1: bfloat16 is faster). Whole trainings
also make their draws and crops, which autocast does not touch: see docs/training.md for job-level numbers.
"""

from __future__ import annotations

import argparse
import statistics
import time


def step_times(depth: int, side: int, n_condition: int, rounds: int, device: str) -> dict[str, float]:
    """Median seconds per training step for float32 and bfloat16 autocast, interleaved."""
    import torch

    from metraw.segment.model import Segmenter
    from metraw.segment.train import TrainConfig, make_optimizer

    nets, opts = {}, {}
    for precision in ("float32", "bfloat16"):
        torch.manual_seed(0)
        nets[precision] = Segmenter(4, 16, depth, n_condition=n_condition).to(device)
        opts[precision] = make_optimizer(nets[precision], TrainConfig(learning_rate=1e-3), device)
    x = torch.randn(8, 4, side, side, device=device)
    y = (torch.rand(8, 4, side, side, device=device) > 0.9).float()
    c = torch.randn(8, n_condition, device=device) if n_condition else None
    times: dict[str, list[float]] = {"float32": [], "bfloat16": []}
    for i in range(rounds + 3):
        for precision, net in nets.items():
            if device != "cpu":
                torch.cuda.synchronize()
            t0 = time.perf_counter()
            with torch.autocast(torch.device(device).type, dtype=torch.bfloat16, enabled=precision == "bfloat16"):
                logits = net(x) if c is None else net(x, c)
            loss = torch.nn.functional.binary_cross_entropy_with_logits(logits.float(), y)
            opts[precision].zero_grad(set_to_none=True)
            loss.backward()
            opts[precision].step()
            if device != "cpu":
                torch.cuda.synchronize()
            if i >= 3:
                times[precision].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=21, help="timed steps per precision and case (median)")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads (the profiles use 1)")
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args()

    import torch

    from metraw.segment.train import BF16_CPU_PROBES, resolve_precision

    torch.set_num_threads(args.threads)
    probes = ", ".join(f"{name} {getattr(torch.cpu, name, lambda: None)()}" for name in BF16_CPU_PROBES)
    print(f"torch {torch.__version__}, device {args.device}, {args.threads} thread(s), CPU capability "
          f"{torch.backends.cpu.get_cpu_capability()}, {probes}: precision auto -> "
          f"{resolve_precision('auto', args.device)}")
    print(f"{'case':<28} {'float32 ms':>10} {'bfloat16 ms':>11} {'ratio':>6}")
    for name, depth, side, n_condition in (("default, 34 px, conditioned", 2, 34, 6),
                                           ("default, 64 px, conditioned", 2, 64, 6),
                                           ("source, 64 px", 3, 64, 0)):
        t = step_times(depth, side, n_condition, args.rounds, args.device)
        print(f"{name:<28} {1e3 * t['float32']:10.1f} {1e3 * t['bfloat16']:11.1f} {t['float32'] / t['bfloat16']:6.2f}")


if __name__ == "__main__":
    main()
