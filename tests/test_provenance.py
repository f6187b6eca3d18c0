"""metraw.provenance: the code digest that keys the aggregate's cached outputs."""

from __future__ import annotations

import shutil
from pathlib import Path

from metraw.provenance import code_digest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "metraw"


def test_code_digest_follows_every_source_file_and_nothing_else(tmp_path):
    pkg = tmp_path / "metraw"
    shutil.copytree(PACKAGE, pkg, ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    first = code_digest(pkg)
    assert first == code_digest(pkg) == code_digest(PACKAGE) and len(first) == 64  # caches and builds left out
    (pkg / "__pycache__").mkdir(exist_ok=True)
    (pkg / "__pycache__" / "spec.cpython-311.pyc").write_bytes(b"\0" * 16)
    (pkg / "codec" / "_simd.cpython-311-x86_64-linux-gnu.so").write_bytes(b"\x7fELF")
    assert code_digest(pkg) == first
    spec = pkg / "spec" / "tolerance.py"
    spec.write_text(spec.read_text() + "\n# one more line\n")
    changed = code_digest(pkg)
    assert changed != first
    (pkg / "spec" / "tolerance.py").rename(pkg / "spec" / "tolerance2.py")  # the same bytes under another name
    assert code_digest(pkg) not in (first, changed)
    (pkg / "spec" / "tolerance2.py").rename(pkg / "spec" / "tolerance.py")
    assert code_digest(pkg) == changed
    (pkg / "schemas" / "params.schema.yaml").write_text("{}\n")  # data files that shape behaviour count
    assert code_digest(pkg) != changed


def test_the_aggregate_rule_keys_its_cache_on_the_code():
    root = PACKAGE.parents[1]
    aggregate = (root / "workflow" / "rules" / "aggregate.smk").read_text()
    common = (root / "workflow" / "rules" / "common.smk").read_text()
    rule = aggregate[aggregate.index("rule aggregate:"):]
    assert "cache: True" in rule and "code=METRAW_CODE" in rule[:rule.index("cache: True")]
    assert "METRAW_CODE = code_digest()" in common
