"""Cycles of the codec's compiled hot loops on CPU models this host is not, by llvm-mca (issue #52).

The codec's speed must hold on CPUs one may not have at hand (an AMD Zen 3, an Intel Haswell). This estimates it
statically: it runs the codec on one frame under ``perf record`` (one thread, the path given), takes from the built
extension (``objdump``) the hottest loop of each kernel that holds at least ``MIN_SHARE`` of the run's samples
(the smallest loop holding ``LOOP_SHARE`` of its function's samples, its blocks without samples left out: escapes,
rare branches), and has ``llvm-mca`` simulate that loop's steady state on each CPU model's scheduling model (LLVM's
own, as its compilers use them). It prints cycles per iteration, per model, and each model's cycles against the
first one's.

What it is good for: comparing loops, builds and models, not absolute times. On this repository's 2-core Intel Xeon
(Emerald Rapids) the ``icelake-server`` figures came within ~20-30 % of measured times (docs/codec-speed.md). What it
cannot see: cache misses, branch mispredictions, and instructions a model prices wrongly: LLVM 14's ``znver3``
model counts an AVX2 gather as one uop of 5 cycles, where a Zen 3 takes ~39 uops (uops.info): a loop with a gather
is flagged in the output, and its Zen 3 figure means nothing.

Needs ``perf`` (Debian: linux-perf), ``llvm-mca`` (Debian: llvm) and ``objdump`` (binutils) on an x86-64 Linux host.

Run: python benchmarks/codec_loops_mca.py [--path avx2] [--cpus znver3,icelake-server,haswell] [--frame canon_dng]
[--calls 40]
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: CPU models by default: AMD Zen 3 (AVX2, no AVX-512), Intel Ice Lake server (the nearest LLVM 14 model to the Xeons
#: these figures were checked on), Intel Haswell (the first AVX2 CPU).
CPUS = ("znver3", "icelake-server", "haswell")
MIN_SHARE = 0.02          # kernels with a smaller share of the run's samples are left out
LOOP_SHARE = 0.7          # the loop analysed: the smallest one holding this share of its function's samples
COLD_BLOCK = 0.002        # a block with fewer samples a instruction than this share of its loop's is left out
ITERATIONS = 300

_WORKLOAD = """
import sys, warnings
sys.path.insert(0, {bench!r})
import codec as bench
from metraw import codec
codec.THREADS = 1
frames = dict(bench.frames())
if {frame!r} not in frames:
    sys.exit(f"no benchmark frame {frame!r} (frames: {{', '.join(frames)}})")
img = frames[{frame!r}]
warnings.simplefilter("ignore")
blob = codec.encode(img, 1.0, 0)
for _ in range({calls}):
    codec.encode(img, 1.0, 0)
    codec.decode(blob, profile=img.profile)
"""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--path", default="avx2", help="codec path to analyse (METRAW_NATIVE; default avx2)")
    ap.add_argument("--cpus", default=",".join(CPUS), help=f"llvm-mca CPU models (default {','.join(CPUS)}; "
                                                          "llvm-mca -mcpu=help lists them)")
    ap.add_argument("--frame", default="canon_dng", help="benchmark frame encoded and decoded (default canon_dng)")
    ap.add_argument("--calls", type=int, default=40, help="encodes and decodes recorded (default 40)")
    return ap.parse_args(argv)


def _instructions(asm: str, name: str) -> list[list[tuple[int, str]]]:
    """Each function called ``name`` in ``objdump -d`` output (static functions repeat per path): its (address,
    instruction) pairs, comments dropped."""
    out = []
    for body in asm.split(f"<{name}>:\n")[1:]:
        ins = []
        for line in body.split("\n\n", 1)[0].splitlines():
            m = re.match(r"\s+([0-9a-f]+):\s+(.*)", line)
            if m:
                ins.append((int(m.group(1), 16), re.sub(r"\s+#.*", "", m.group(2)).strip()))
        if ins:
            out.append(ins)
    return out


def _target(ins: str) -> int | None:
    m = re.match(r"j\w+\s+([0-9a-f]+) <", ins)
    return int(m.group(1), 16) if m else None


def hot_loop(ins: list[tuple[int, str]], samples: dict[int, int]) -> tuple[list[str], int, int, float] | None:
    """The instructions of the smallest loop (a backward branch's range) holding ``LOOP_SHARE`` of the function's
    samples, without its blocks that have (next to) none, branches left out; with its first and last address and
    its share of the function's samples. None where no loop holds that share."""
    total = sum(samples.get(a, 0) for a, _ in ins)
    loops = []
    for a, t in ins:
        lo = _target(t)
        if lo is not None and lo <= a:
            s = sum(samples.get(b, 0) for b, _ in ins if lo <= b <= a)
            if total and s >= LOOP_SHARE * total:
                loops.append((a - lo, lo, a, s))
    if not loops:
        return None
    _, lo, hi, s = min(loops)
    body = [(a, t) for a, t in ins if lo <= a <= hi]
    targets = {_target(t) for _, t in body} - {None}
    blocks, cur = [], []
    for a, t in body:
        if a in targets and cur:
            blocks.append(cur)
            cur = []
        cur.append((a, t))
        if t.startswith("j"):
            blocks.append(cur)
            cur = []
    blocks.append(cur)
    kept = [t for b in blocks if b and sum(samples.get(a, 0) for a, _ in b) > COLD_BLOCK * s * len(b)
            for _, t in b if not t.startswith("j") and "nop" not in t]
    return kept, lo, hi, s / total


def mca_cycles(lines: list[str], cpu: str) -> float:
    """llvm-mca's cycles per iteration of ``lines`` (a loop body) in steady state on ``cpu``."""
    r = subprocess.run(["llvm-mca", f"-mcpu={cpu}", f"-iterations={ITERATIONS}"], input="\n".join(lines) + "\n",
                       capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(f"llvm-mca -mcpu={cpu}: {r.stderr.strip().splitlines()[0]}")
    return int(re.search(r"Total Cycles:\s+(\d+)", r.stdout).group(1)) / ITERATIONS


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    missing = [t for t in ("perf", "llvm-mca", "objdump") if not shutil.which(t)]
    if missing:
        print(f"codec_loops_mca: needs {', '.join(missing)} on PATH (Debian: linux-perf, llvm, binutils)",
              file=sys.stderr)
        return 2
    from metraw.codec import native

    if native.LIB is None or args.path not in native.AVAILABLE:
        print(f"codec_loops_mca: the {args.path} path is not built or not run by this CPU "
              f"(available: {', '.join(native.AVAILABLE) or 'none'})", file=sys.stderr)
        return 2
    so = native.LIB._name
    cpus = args.cpus.split(",")
    try:   # an unknown CPU model: one line now, not after the recording
        for cpu in cpus:
            mca_cycles(["add %rax, %rbx"], cpu)
    except RuntimeError as exc:
        print(f"codec_loops_mca: {exc}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "perf.data"
        code = _WORKLOAD.format(bench=str(ROOT / "benchmarks"), frame=args.frame, calls=args.calls)
        env = {**os.environ, "METRAW_NATIVE": args.path}
        r = subprocess.run(["perf", "record", "-q", "-F", "4000", "-o", str(data), sys.executable, "-c", code],
                           env=env, capture_output=True, text=True)
        if r.returncode:
            print(f"codec_loops_mca: perf record failed: {(r.stderr.strip() or 'no message').splitlines()[-1]}",
                  file=sys.stderr)
            return 2
        # the extension's functions by samples, then each one's samples by instruction (perf annotate gives the
        # library's own addresses, as objdump does)
        report = subprocess.run(["perf", "report", "-i", str(data), "--stdio", "--no-children", "--sort", "dso,sym",
                                 "--percent-limit", str(100 * MIN_SHARE)], capture_output=True, text=True).stdout
        by_fn: dict[str, float] = {}
        for line in report.splitlines():
            m = re.match(r"\s+([0-9.]+)%\s+(\S+)\s+\[\.\]\s+(\S+)", line)
            if m and m.group(2) == Path(so).name:
                by_fn[m.group(3)] = float(m.group(1)) / 100
        samples: dict[str, dict[int, float]] = {}
        for fn in by_fn:
            ann = subprocess.run(["perf", "annotate", "-i", str(data), "--stdio", "-s", fn], capture_output=True,
                                 text=True).stdout
            pct: dict[int, float] = collections.Counter()
            for line in ann.splitlines():
                m = re.match(r"\s+([0-9.]+)\s+:\s+([0-9a-f]+):", line)
                if m:
                    pct[int(m.group(2), 16)] += float(m.group(1))
            samples[fn] = pct
    asm = subprocess.run(["objdump", "-d", "--no-show-raw-insn", so], capture_output=True, text=True).stdout
    version = subprocess.run(["llvm-mca", "--version"], capture_output=True, text=True).stdout
    version = re.search(r"version\s+(\S+)", version).group(1) if "version" in version else "?"
    print(f"# {args.path} path, {args.frame} encoded and decoded {args.calls} times on one thread; llvm-mca {version}, "
          f"{ITERATIONS} iterations a loop")
    print(f"{'kernel':28s} {'share':>5s} {'loop':>13s} {'insns':>5s} " + " ".join(f"{c:>14s}" for c in cpus)
          + f"  {cpus[0]} / others")
    if not by_fn:
        print(f"# no kernel of {Path(so).name} took {MIN_SHARE:.0%} of the run's samples: more --calls")
    for fn, share in sorted(by_fn.items(), key=lambda kv: -kv[1]):
        copies = _instructions(asm, fn)
        if not copies:
            continue
        pct = samples[fn]
        ins = max(copies, key=lambda c: sum(pct.get(a, 0) for a, _ in c))
        loop = hot_loop(ins, pct)
        if loop is None:
            print(f"{fn:28s} {share:5.1%} (no loop holds {LOOP_SHARE:.0%} of its samples)")
            continue
        lines, lo, hi, _ = loop
        cyc = [mca_cycles(lines, c) for c in cpus]
        flag = "  gathers: the AMD figure is not to be trusted" if any("gather" in t for t in lines) else ""
        print(f"{fn:28s} {share:5.1%} {lo:6x}-{hi:6x} {len(lines):5d} " + " ".join(f"{c:14.1f}" for c in cyc)
              + "  " + " ".join(f"{cyc[0] / c:.2f}" for c in cyc[1:]) + flag)
    print("# cycles per iteration of each kernel's hot loop (one iteration: a step of the kernel's vectors, e.g. 4 "
          "or 8 pixels, or one lane step of the decoder); share: of the run's samples")
    return 0


if __name__ == "__main__":
    sys.exit(main())
