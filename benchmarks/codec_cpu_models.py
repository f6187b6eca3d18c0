"""The codec as it runs on other CPUs: each CPU model emulated by QEMU in user mode (issue #52).

``qemu-x86_64 -cpu MODEL`` runs this machine's Python with MODEL's CPUID, and its translator (TCG) executes only the
instructions it emulates: SSE to AVX2, FMA and BMI2 since QEMU 7.2, no AVX-512 at all. So a run under EPYC-Milan (AMD
Zen 3) or Haswell is a run on an AVX2-only CPU as far as correctness goes: the codec's run-time dispatch reads that
CPUID (no ``METRAW_NATIVE``), numba's LLVM compiles for it, numpy dispatches for it, and one AVX-512 instruction
anywhere ends the run with SIGILL. Under Westmere (SSE4.2, no AVX) the compiled paths are those without AVX2.

For each model this checks:
- which codec paths the extension offers there (``native.AVAILABLE``) and which one the codec picks by itself
  (``native.PATH``), against what the model's CPUID says (AVX2 + FMA + BMI2: avx2; none of AVX-512: no avx512);
- that every path offered there, and numba, writes the same stream and decodes the same values as this host's own
  paths do: SHA-256 of the blob and of the decoded pixels of every benchmark frame (``codec.frames()``: the three
  real frames, a synthetic 1.5 MP frame, three small faint ones) at steps 0.5, 1 and 2, on 1 and 2 threads;
- that the stored version-3 fixtures (tests/fixtures/codec) decode there to their recorded pixels, on every path.

``--models arm64`` (with ``--arm64-root DIR``, made by ``benchmarks/arm64_root.sh DIR``: Debian's arm64 Python 3.11, the
arm64 wheels of the host's versions, the extension cross-compiled) runs the same checks on 64-bit ARM under
qemu-aarch64: the portable C path (NEON) and numba there against this host's bytes.

Speed under emulation means nothing (TCG runs SIMD code 10-100x slower, and differently); this checks only what runs
and what it computes. The first run of a model compiles numba's loops for it (minutes; cached per CPU name after).
Needs ``qemu-x86_64`` (Debian/Ubuntu: ``apt-get install qemu-user``) on an x86-64 Linux host.

Run: python benchmarks/codec_cpu_models.py [--models EPYC-Milan,Haswell,Westmere[,arm64 --arm64-root DIR]]
[--frames canon_dng,...] [--jobs N]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests"))

#: CPU models run by default: AMD Zen 3 (AVX2, no AVX-512: the host most users have), Intel Haswell (the first AVX2
#: CPU), Intel Westmere (SSE4.2, no AVX).
MODELS = ("EPYC-Milan", "Haswell", "Westmere")
STEPS = (0.5, 1.0, 2.0)
THREADS = (1, 2)


def _sha(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()[:16]


def cpu_report() -> dict:
    """What this process's CPU reports (CPUID, not /proc/cpuinfo, which QEMU passes through from the host) and what
    the codec made of it."""
    import llvmlite.binding as ll

    from metraw.codec import native

    have = ll.get_host_cpu_features()
    return {"llvm_cpu": ll.get_host_cpu_name(),
            "cpuid": [f for f in ("sse4.2", "avx", "avx2", "fma", "bmi2", "avx512f", "avx512dq") if have.get(f)],
            "available": list(native.AVAILABLE), "picked": native.PATH, "two_vectors": native.TWO_VECTORS}


def hashes(names: list[str] | None) -> dict[str, list[str]]:
    """Per codec path this CPU runs (and numba): one line per frame, step and thread count with the SHA-256 of the
    stream and of the decoded pixels; then one per stored fixture with the SHA-256 of its decoded pixels."""
    import codec as bench   # benchmarks/codec.py
    import test_codec_format as fixtures

    from metraw import codec
    from metraw.codec import native

    frames = bench.frames()
    unknown = sorted(set(names or ()) - {n for n, _ in frames})
    if unknown:
        raise ValueError(f"no benchmark frame {', '.join(unknown)} (frames: {', '.join(n for n, _ in frames)})")
    frames = [(n, img) for n, img in frames if names is None or n in names]
    out = {}
    for path in native.AVAILABLE + ("numba",):
        lines = []
        with native.path_in_use(path):
            for name, img in frames:
                for step in STEPS:
                    for threads in THREADS:
                        with codec.threads(threads):
                            blob = codec.encode(img, step)
                            dec = codec.decode(blob).data
                        lines.append(f"{name} step {step} threads {threads}: {_sha(blob)} {_sha(dec.tobytes())}")
            for name in sorted(fixtures.FIXTURES):
                dec = codec.decode((fixtures.HERE / name).read_bytes()).data
                pixels = fixtures._sha(np.ascontiguousarray(dec, "<u2").tobytes())
                lines.append(f"fixture {name}: {'recorded' if pixels == fixtures.FIXTURES[name][2] else pixels} pixels")
        out[path] = lines
    return out


def expected_paths(model: str, cpuid: list[str]) -> set[str]:
    """The compiled paths a CPU model with these CPUID features must be offered (``metraw_simd_paths``): on ARM the
    portable one only."""
    want = {"portable"}
    if model == "arm64":
        return want
    if {"avx2", "fma", "bmi2"} <= set(cpuid):
        want.add("avx2")
    if {"avx512f", "avx512dq"} <= set(cpuid):
        want.add("avx512")
    return want


def child(names: list[str] | None) -> None:
    warnings.simplefilter("ignore")
    print(json.dumps({**cpu_report(), "hashes": hashes(names)}))


def run_model(model: str, names: list[str] | None, arm64_root: Path | None) -> dict:
    """This script's checks (``--child``) run under QEMU as ``model``: its report, or {"error": ...}."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("METRAW_NATIVE", "NUMBA_CPU", "NPY_DISABLE"))}
    if model == "arm64":
        root = arm64_root / "root"
        cmd = ["qemu-aarch64", "-L", str(root), str(root / "usr/bin/python3.11")]
        env.update(PYTHONPATH=f"{arm64_root / 'site'}:{arm64_root / 'src'}", PYTHONNOUSERSITE="1",
                   NUMBA_CACHE_DIR=str(arm64_root / "numba_cache"))
    else:
        cmd = ["qemu-x86_64", "-cpu", model, sys.executable]
    cmd += [__file__, "--child"] + (["--frames", ",".join(names)] if names else [])
    t = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t
    if res.returncode != 0:
        err = [ln for ln in res.stderr.splitlines() if "TCG doesn't support" not in ln]
        sigill = " (SIGILL: an instruction this CPU lacks)" if res.returncode == -signal.SIGILL else ""
        return {"error": f"exit {res.returncode}{sigill}: " + " | ".join(err[-3:]), "wall_s": wall}
    return {**json.loads(res.stdout.splitlines()[-1]), "wall_s": wall}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default=",".join(MODELS), help=f"QEMU CPU models (default {','.join(MODELS)}; "
                                                               "qemu-x86_64 -cpu help lists them)")
    ap.add_argument("--frames", help="benchmark frames to check, comma-separated (default: all)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                    help="models run at once (default: one per core)")
    ap.add_argument("--arm64-root", type=Path, help="for the model arm64: the folder benchmarks/arm64_root.sh made")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error("--jobs must be >= 1")
    names = args.frames.split(",") if args.frames else None
    if args.child:
        child(names)
        return 0
    models = args.models.split(",")
    problem = ("needs an x86-64 Linux host" if os.uname().machine != "x86_64" else
               "needs qemu-x86_64 (apt-get install qemu-user)" if shutil.which("qemu-x86_64") is None else
               "--models arm64 needs --arm64-root DIR, made by benchmarks/arm64_root.sh DIR"
               if "arm64" in models and not (args.arm64_root and (args.arm64_root / "root").is_dir()) else None)
    if problem:
        print(f"codec_cpu_models: {problem}", file=sys.stderr)
        return 2
    from metraw.codec import native

    warnings.simplefilter("ignore")
    try:
        ref = hashes(names)
    except ValueError as exc:   # an unknown --frames name
        print(f"codec_cpu_models: {exc}", file=sys.stderr)
        return 2
    version = subprocess.run(["qemu-x86_64", "--version"], capture_output=True, text=True).stdout.splitlines()[0]
    host = cpu_report()
    print(f"# host: {native.cpu()}; LLVM: {host['llvm_cpu']}; paths {', '.join(host['available'])}; {version}")
    ref_lines = ref["numba"]
    agree = [p for p, lines in ref.items() if lines == ref_lines]
    print(f"# host paths with the same streams and values as numba: {', '.join(agree)} of {', '.join(ref)} "
          f"({len(ref_lines)} checks each)")
    recorded = all(ln.endswith("recorded pixels") for ln in ref_lines if ln.startswith("fixture "))
    print(f"# the stored fixtures decode here to their recorded pixels: {'yes' if recorded else 'NO'}")
    ok = len(agree) == len(ref) and recorded
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:   # each model in its own QEMU process
        runs = [pool.submit(run_model, model, names, args.arm64_root) for model in models]
    for model, run in zip(models, runs):
        got = run.result()
        if "error" in got:
            print(f"{model}: FAILED after {got['wall_s']:.0f} s, {got['error']}")
            ok = False
            continue
        want = expected_paths(model, got["cpuid"])
        same = [p for p, lines in got["hashes"].items() if lines == ref_lines]
        good = set(got["available"]) == want and len(same) == len(got["hashes"])
        ok &= good
        halves = "as two vectors" if got["two_vectors"] else "in 8-row halves"
        print(f"{model}: {'ok' if good else 'FAILED'}: CPU features {' '.join(got['cpuid']) or 'none listed'}, LLVM "
              f"{got['llvm_cpu']}; paths offered {', '.join(got['available']) or 'none'} (expected "
              f"{', '.join(sorted(want))}), picked {got['picked']} (16-lane groups {halves}); same streams and "
              f"values as the host on {', '.join(same)} of {', '.join(got['hashes'])}; {got['wall_s']:.0f} s under "
              f"QEMU")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
