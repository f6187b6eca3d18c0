"""benchmarks/codec_loops_mca.py: the hot loop it hands to llvm-mca (pure parsing; llvm-mca and perf not needed)."""

from __future__ import annotations

import importlib.util
from pathlib import Path


def _tool():
    spec = importlib.util.spec_from_file_location(
        "metraw_codec_loops_mca", Path(__file__).resolve().parents[1] / "benchmarks" / "codec_loops_mca.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_hot_loop_is_the_smallest_holding_most_samples_without_its_cold_blocks():
    """An outer loop (0x10-0x40) around an inner one (0x18-0x34) whose escape block (0x24-0x28) has no samples: the
    inner loop's instructions without the escape block and without branches, and its share of the samples."""
    ins = [(0x10, "mov %rdi,%rax"), (0x18, "vpaddq %ymm1,%ymm2,%ymm3"), (0x1c, "vpmuldq %ymm3,%ymm4,%ymm5"),
           (0x20, "je 2c <f+0x1c>"), (0x24, "vpgatherqd %xmm7,(%r13,%ymm6,4),%xmm5"), (0x28, "add $0x1,%rcx"),
           (0x2c, "vpsubq %ymm5,%ymm1,%ymm1"), (0x30, "cmp %rcx,%rdx"), (0x34, "jne 18 <f+0x8>"),
           (0x38, "add $0x8,%rdi"), (0x3c, "cmp %rdi,%rsi"), (0x40, "jne 10 <f>")]
    samples = {0x18: 30, 0x1c: 25, 0x20: 5, 0x2c: 20, 0x30: 10, 0x34: 5, 0x38: 3, 0x10: 2}
    lines, lo, hi, share = _tool().hot_loop(ins, samples)
    assert (lo, hi) == (0x18, 0x34)
    assert lines == ["vpaddq %ymm1,%ymm2,%ymm3", "vpmuldq %ymm3,%ymm4,%ymm5", "vpsubq %ymm5,%ymm1,%ymm1",
                     "cmp %rcx,%rdx"]
    assert abs(share - 95 / 100) < 1e-12
    # no loop holds LOOP_SHARE of the samples (half of them after the loops): None
    assert _tool().hot_loop(ins + [(0x44, "ret")], {0x10: 50, 0x44: 50}) is None


def test_functions_of_one_name_are_each_read_from_objdump():
    """Static functions repeat per codec path under one name: each copy's instructions, comments dropped."""
    asm = ("0000000000001000 <steady8>:\n    1000:\tvpaddq %ymm1,%ymm2,%ymm3\n    1004:\tret\n\n"
           "0000000000002000 <other>:\n    2000:\tret\n\n"
           "0000000000003000 <steady8>:\n    3000:\tvpaddq 0x10(%rip),%ymm2,%ymm3        # 3020 <x>\n\n")
    copies = _tool()._instructions(asm, "steady8")
    assert copies == [[(0x1000, "vpaddq %ymm1,%ymm2,%ymm3"), (0x1004, "ret")],
                      [(0x3000, "vpaddq 0x10(%rip),%ymm2,%ymm3")]]
