"""The shape of the package, read from its source with ``ast`` (nothing is imported): the import graph has no
cycles, no module takes a ``_private`` name (or module) from another package, no module is over
``MAX_LINES`` lines, and the packages stand on floors that read as the data flows: a module imports only from
its own floor or lower ones. Imports inside functions count as much as those at the top of a module.

Floors (``FLOORS``): the base utilities (errors, atomic writes, workers, progress, provenance, allocator) ->
the raw image's data model (``raw``) -> its physics and the codec (``physics``, ``codec``) -> reading and
writing images and stores (``io``) -> calibration, a study's parameters and sources, synthetic scenes
(``calibrate``, ``study``, ``scenes``) -> emulation (``emulate``) -> segmentation and the specification
(``segment``, ``spec``) -> the command line (``cli``) -> the workflow (Snakefile, workflow/), which may import
anything; the top-level ``metraw`` module is the package's face (RawImage, CalibrationProfile, MetrawError).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"

#: The longest a module may be.
MAX_LINES = 700

#: Floor of each unit: a package of metraw (``metraw.raw``: every module inside it) or a module directly in
#: metraw (``metraw.errors``). Lower floors must not import higher ones.
FLOORS = {
    "metraw.errors": 0, "metraw.atomic": 0, "metraw.parallel": 0, "metraw.progress": 0, "metraw.provenance": 0,
    "metraw.allocator": 0,
    "metraw": 1, "metraw.raw": 1,
    "metraw.physics": 2, "metraw.codec": 2,
    "metraw.io": 3,
    "metraw.calibrate": 4, "metraw.study": 4, "metraw.scenes": 4,
    "metraw.emulate": 5,
    "metraw.segment": 6, "metraw.spec": 6,
    "metraw.cli": 7, "metraw.__main__": 7,
}


def source_modules(src: Path = SRC) -> dict[str, tuple[Path, str]]:
    """``{module name: (file, package it belongs to)}`` of every .py file of metraw under ``src``."""
    out = {}
    for path in sorted((src / "metraw").rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
            package = ".".join(parts)
        else:
            package = ".".join(parts[:-1])
        out[".".join(parts)] = (path, package)
    return out


def _resolve(name: str, modules) -> str | None:
    """The module ``name`` is (or lies in, for ``module.attribute``), or None outside metraw."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def imports(modules) -> list[tuple[str, str, str | None]]:
    """Every import of a metraw module by a metraw module, at any depth of the source: (importer, imported module,
    name taken from it or None for a module imported as such)."""
    out = []
    for name, (path, package) in modules.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    target = _resolve(alias.name, modules)
                    if target:
                        out.append((name, target, None))
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[:len(base) - node.level + 1]
                    source = ".".join(base + ([node.module] if node.module else []))
                else:
                    source = node.module or ""
                if not (source == "metraw" or source.startswith("metraw.")):
                    continue
                for alias in node.names:
                    if f"{source}.{alias.name}" in modules:  # a module: from metraw.io import store
                        out.append((name, f"{source}.{alias.name}", None))
                    else:
                        out.append((name, _resolve(source, modules), alias.name))
    return out


def unit_of(module: str) -> str:
    """``metraw.raw.cfa`` -> ``metraw.raw``; a module directly in metraw (``metraw.errors``) is its own unit."""
    parts = module.split(".")
    if len(parts) >= 2 and f"metraw.{parts[1]}" in FLOORS and (len(parts) > 2 or _is_package(parts[1])):
        return f"metraw.{parts[1]}"
    return module


def _is_package(name: str) -> bool:
    return (SRC / "metraw" / name / "__init__.py").is_file()


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    counter = 0
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def violations(src: Path = SRC) -> dict[str, list[str]]:
    """What breaks the rules in the source under ``src``, per rule (empty lists: none)."""
    modules = source_modules(src)
    found = imports(modules)
    edges: dict[str, set[str]] = {}
    for importer, target, _ in found:
        if target != importer:
            edges.setdefault(importer, set()).add(target)
    private = []
    for importer, target, name in found:
        package = modules[importer][1]
        target_package = modules[target][1] if target in modules else None
        if target_package == package:
            continue
        # a private module (metraw.io._unknown) of another package, or a private name of another package's module
        if any(_private(part) for part in target.split(".")):
            private.append(f"{importer} imports the private module {target}")
        elif name is not None and _private(name):
            private.append(f"{importer} imports {name} from {target} (another package)")
    upward = []
    for importer, target, _ in found:
        a, b = unit_of(importer), unit_of(target)
        if a == b:
            continue
        if a not in FLOORS or b not in FLOORS:
            upward.append(f"{importer} -> {target}: {a if a not in FLOORS else b} has no floor in FLOORS")
        elif FLOORS[b] > FLOORS[a]:
            upward.append(f"{importer} (floor {FLOORS[a]}) imports {target} (floor {FLOORS[b]})")
    long = [f"{name}: {n} lines" for name, (path, _) in modules.items()
            if (n := len(path.read_text().splitlines())) > MAX_LINES]
    return {"cycles": [" -> ".join(c) for c in cycles(edges)], "private": sorted(set(private)),
            "upward": sorted(set(upward)), "long": long}


def test_the_graph_is_read():
    modules = source_modules()
    found = imports(modules)
    assert {"metraw.raw.cfa", "metraw.emulate.emulator", "metraw.cli.emulate", "metraw.io.labels"} <= set(modules)
    assert ("metraw.emulate.emulator", "metraw.emulate.plan", "plan_emulation") in found
    # an import inside a function counts: io.labels reads its mask pictures through io.pictures there
    assert any(i == "metraw.io.labels" and t == "metraw.io.pictures" for i, t, _ in found)
    assert all(unit_of(m) in FLOORS for m in modules), sorted(m for m in modules if unit_of(m) not in FLOORS)


@pytest.mark.parametrize("rule", ["cycles", "private", "upward", "long"])
def test_the_package_keeps_its_architecture(rule):
    assert violations()[rule] == []


@pytest.mark.parametrize("rule, planted", [
    ("cycles", ("raw/profile.py", "\n\ndef _planted():\n    from metraw.raw.image import RawImage\n")),
    ("private", ("spec/check.py", "\n\ndef _planted():\n    from metraw.io._unknown import unknown_fields\n")),
    ("private", ("segment/toy.py", "\n\ndef _planted():\n    from metraw.emulate.emulator import _detect\n")),
    ("upward", ("physics/optics.py", "\n\ndef _planted():\n    from metraw.emulate.target import TargetSystem\n")),
    ("long", ("raw/cfa.py", "\n" * (MAX_LINES + 1))),
])
def test_a_planted_violation_is_found(tmp_path, rule, planted):
    """Each rule finds a breach planted in a copy of the source (raw.image imports raw.profile, so profile importing
    image closes a cycle)."""
    import shutil

    shutil.copytree(SRC / "metraw", tmp_path / "metraw", ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    path, text = planted
    with open(tmp_path / "metraw" / path, "a") as fh:
        fh.write(text)
    assert violations(tmp_path)[rule], rule


def test_the_workflow_imports_modules_that_exist():
    """The Snakefile, its rules and scripts import metraw at parse time: every module they name exists."""
    modules = source_modules()
    files = [REPO / "Snakefile", *sorted((REPO / "workflow").rglob("*.smk")), *sorted((REPO / "workflow").rglob("*.py"))]
    named = []
    for path in files:
        for match in re.finditer(r"^\s*(?:from\s+(metraw[\w.]*)\s+import|import\s+(metraw[\w.]*))", path.read_text(),
                                 re.MULTILINE):
            named.append((path.name, match.group(1) or match.group(2)))
    assert named, "no metraw import found in the workflow"
    assert [(f, m) for f, m in named if m not in modules] == []
