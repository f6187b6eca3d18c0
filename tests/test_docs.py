"""The repository's documentation stands on its own: cited pages exist, relative links resolve, and nothing cites
design notes kept outside the repository. The README is the front door: short, the main job's and the test command
in its first lines, every docs page reachable from it (directly or through docs/index.md), and the changelog linked.

Fast, standard library only, no network.
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: A repository path of a documentation page, e.g. ``docs/emulation.md``.
DOC_PATH = re.compile(r"(?<![\w./-])docs/[\w./-]+\.md(?!\w)")
#: Inline links and images ``[text](target)`` / ``[text](<target> "title")``.
INLINE_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*(<[^>]*>|[^\s()]+(?:\([^\s()]*\)[^\s()]*)*)")
#: Reference definitions ``[label]: target``.
REFERENCE = re.compile(r"^[ ]{0,3}\[[^\]]+\]:\s*(<[^>]*>|\S+)", re.MULTILINE)
FENCE = re.compile(r"^[ ]{0,3}(```|~~~).*?^[ ]{0,3}\1[^\n]*$", re.MULTILINE | re.DOTALL)
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1", re.DOTALL)
EXTERNAL = re.compile(r"^(https?:|mailto:)", re.IGNORECASE)
#: What the repository must not cite: design notes that live outside it (spelled apart so this file does not).
OUTSIDE_NOTES = "DESIGN" + ".md"
#: Where that citation must not appear: whole folders and single files of the repository.
NO_OUTSIDE_NOTES = ("src", "tests", "workflow", "benchmarks", "README.md", "params.yaml", "dvc.yaml")


# ----------------------------------------------------------------------------- helpers
def doc_paths(text: str) -> list[str]:
    """Every ``docs/<name>.md`` path mentioned in ``text`` (repository-relative), in order."""
    return DOC_PATH.findall(text)


def missing_doc_paths(text: str, root: Path = ROOT) -> list[str]:
    """The ``docs/<name>.md`` paths of ``text`` that are no file under ``root``."""
    return [p for p in doc_paths(text) if not (root / p).is_file()]


def _without_code(text: str) -> str:
    """``text`` without fenced code blocks and inline code spans (their brackets are no links)."""
    return CODE_SPAN.sub("", FENCE.sub("", text))


def link_targets(text: str) -> list[str]:
    """Targets of the Markdown links and images of ``text`` (inline and reference definitions)."""
    body = _without_code(text)
    return [t.strip("<>") for t in INLINE_LINK.findall(body) + REFERENCE.findall(body)]


def is_local(target: str) -> bool:
    """Whether a link target names a file: not http(s), mailto, or an anchor within the page."""
    return bool(target) and not target.startswith("#") and not EXTERNAL.match(target)


def broken_links(markdown: Path, root: Path = ROOT) -> list[str]:
    """Relative link targets of ``markdown`` that are no existing file or folder inside ``root``.

    The ``#anchor`` is dropped; a target resolved outside ``root`` counts as broken (a clone of the
    repository does not have it)."""
    root = root.resolve()
    bad = []
    for target in link_targets(markdown.read_text(encoding="utf-8")):
        if not is_local(target):
            continue
        path = unquote(target.split("#", 1)[0])
        resolved = (root / path.lstrip("/")) if path.startswith("/") else (markdown.parent / path)
        resolved = resolved.resolve()
        if not resolved.is_relative_to(root) or not resolved.exists():
            bad.append(target)
    return bad


def repository_files(*names: str, root: Path = ROOT) -> list[Path]:
    """Files of the repository under ``names`` (folders or files): those git tracks or would track (ignored build
    outputs such as ``*.egg-info`` left out); every file on disk when ``root`` is not a git work tree."""
    try:
        out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard", "--", *names],
                             cwd=root, capture_output=True, check=True).stdout
        files = [root / os.fsdecode(p) for p in out.split(b"\0") if p]
    except (OSError, subprocess.CalledProcessError):
        files = []
        for name in names:
            p = root / name
            files += [p] if p.is_file() else [q for q in p.rglob("*") if q.is_file()]
    return sorted({f for f in files if f.is_file()})


def _markdown_pages() -> list[Path]:
    pages = [ROOT / "README.md", ROOT / "CHANGELOG.md"] + sorted((ROOT / "docs").rglob("*.md"))
    return [p for p in pages if p.is_file()]


def _rel(p: Path) -> str:
    return p.relative_to(ROOT).as_posix()


# ----------------------------------------------------------------------------- the helpers catch what they must
def test_doc_path_helper_finds_cited_pages_and_flags_missing_ones(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "emulation.md").write_text("# Emulation\n")
    text = ('"""Chain of docs/emulation.md, see also (docs/codec.md).\n'
            "not a page: docs/figures/plot.png, mydocs/x.md, docs/emulation.mdx\n")
    assert doc_paths(text) == ["docs/emulation.md", "docs/codec.md"]
    assert missing_doc_paths(text, tmp_path) == ["docs/codec.md"]


def test_link_helper_extracts_links_and_skips_external_and_code():
    text = ("See [notes](docs/a.md#part), ![fig](<docs/figures/x y.png>), [web](https://example.org/a.md),\n"
            "[mail](mailto:a@b.c), [here](#section), `[code](nowhere.md)`, [ref][r].\n"
            "```\n[fenced](nowhere.md)\n```\n"
            "[r]: ../outside/notes.md\n")
    targets = link_targets(text)
    assert targets == ["docs/a.md#part", "docs/figures/x y.png", "https://example.org/a.md", "mailto:a@b.c",
                       "#section", "../outside/notes.md"]
    assert [t for t in targets if is_local(t)] == ["docs/a.md#part", "docs/figures/x y.png", "../outside/notes.md"]


def test_broken_links_flags_missing_and_outside_targets(tmp_path):
    repo = tmp_path / "repo"
    (repo / "docs").mkdir(parents=True)
    (tmp_path / "outside.md").write_text("exists, but outside the repository\n")
    (repo / "docs" / "ok.md").write_text("[back](../README.md), [self](ok.md#top), [web](http://x.org/y)\n")
    readme = repo / "README.md"
    readme.write_text("[ok](docs/ok.md#a) [gone](docs/missing.md) [out](../outside.md) [anchor](#x)\n")
    assert broken_links(repo / "docs" / "ok.md", repo) == []
    assert broken_links(readme, repo) == ["docs/missing.md", "../outside.md"]


def test_outside_notes_scan_reads_every_file(tmp_path):
    (tmp_path / "src" / "pkg").mkdir(parents=True)
    (tmp_path / "src" / "pkg" / "mod.py").write_text(f'"""See {OUTSIDE_NOTES} section 3."""\n')
    (tmp_path / "src" / "pkg" / "data.bin").write_bytes(b"\0\1" + OUTSIDE_NOTES.encode())
    (tmp_path / "params.yaml").write_text("a: 1\n")
    files = repository_files("src", "params.yaml", root=tmp_path)
    assert [_rel_to(f, tmp_path) for f in files] == ["params.yaml", "src/pkg/data.bin", "src/pkg/mod.py"]
    assert [_rel_to(f, tmp_path) for f in files if OUTSIDE_NOTES.encode() in f.read_bytes()] == [
        "src/pkg/data.bin", "src/pkg/mod.py"]


def _rel_to(p: Path, root: Path) -> str:
    return p.relative_to(root).as_posix()


# ----------------------------------------------------------------------------- the repository
def test_docs_pages_exist():
    for page in ("index", "noise-model", "emulation", "codec", "statistics", "workflow", "training", "sim-to-real",
                 "cli", "benchmarks"):
        assert (ROOT / "docs" / f"{page}.md").is_file(), f"docs/{page}.md is missing"


@pytest.mark.parametrize("path", [_rel(p) for p in sorted((ROOT / "src" / "metraw").rglob("*.py"))]
                         + ["README.md", "CHANGELOG.md", "params.yaml"])
def test_cited_doc_pages_exist(path):
    """(1) Every docs/<name>.md a module, the README or params.yaml mentions is a file of the repository."""
    missing = missing_doc_paths((ROOT / path).read_text(encoding="utf-8"))
    assert not missing, f"{path} cites missing page(s): {', '.join(missing)}"


@pytest.mark.parametrize("path", [_rel(p) for p in _markdown_pages()])
def test_relative_markdown_links_resolve(path):
    """(2) Every relative link of the README and the docs pages names an existing file inside the repository."""
    bad = broken_links(ROOT / path)
    assert not bad, f"{path} has broken relative link(s): {', '.join(bad)}"


def test_nothing_cites_design_notes_outside_the_repository():
    """(3) No file under src/, tests/, workflow/, benchmarks/ and no README.md, params.yaml, dvc.yaml mentions the
    design notes that used to live outside the repository: the pages under docs/ replace them."""
    files = repository_files(*NO_OUTSIDE_NOTES)
    assert len(files) > 10
    needle = OUTSIDE_NOTES.encode()
    hits = [_rel(f) for f in files if needle in f.read_bytes()]
    assert not hits, f"{OUTSIDE_NOTES} is cited in: {', '.join(hits)} (cite the page under docs/ instead)"


def test_nothing_names_a_folder_beside_the_repository():
    # a user's clone has no folder beside it: what the project needs at run or test time lives in it (data/real)
    needle = ("../" + "shared").encode()
    hits = [_rel_to(f, ROOT) for f in repository_files(*NO_OUTSIDE_NOTES) if needle in f.read_bytes()]
    assert not hits, f"a folder outside the repository is named in: {', '.join(hits)}"


# ----------------------------------------------------------------------------- the README is the front door
#: The README's budget of lines, and the part of it a newcomer reads first.
README_MAX_LINES = 250
README_HEAD_LINES = 40
#: The commands a newcomer needs first: the main job and the test command (as ``.ci/run`` runs them).
MAIN_JOB = "snakemake --cores all"
TEST_COMMAND = "python3 -m pytest -q"


def local_link_files(markdown: Path, root: Path = ROOT) -> set[Path]:
    """The existing files that ``markdown``'s relative links name (anchors dropped), resolved."""
    files = set()
    for target in link_targets(markdown.read_text(encoding="utf-8")):
        if not is_local(target):
            continue
        path = unquote(target.split("#", 1)[0])
        resolved = ((root / path.lstrip("/")) if path.startswith("/") else (markdown.parent / path)).resolve()
        if resolved.is_file():
            files.add(resolved)
    return files


def unreachable_pages(root: Path = ROOT) -> list[str]:
    """``docs/*.md`` pages that neither the README nor ``docs/index.md`` (when the README links it) links."""
    readme = root / "README.md"
    index = (root / "docs" / "index.md").resolve()
    reached = local_link_files(readme, root)
    if index in reached:
        reached |= local_link_files(index, root)
    return [_rel_to(p, root) for p in sorted((root / "docs").glob("*.md")) if p.resolve() not in reached]


def test_unreachable_pages_helper(tmp_path):
    (tmp_path / "docs").mkdir()
    for name in ("index", "a", "b", "c"):
        (tmp_path / "docs" / f"{name}.md").write_text(f"# {name}\n")
    (tmp_path / "docs" / "index.md").write_text("[a](a.md) [b](b.md#part)\n")
    (tmp_path / "README.md").write_text("[notes](docs/index.md)\n")
    assert unreachable_pages(tmp_path) == ["docs/c.md"]
    (tmp_path / "README.md").write_text("[c](docs/c.md)\n")  # the index itself no longer linked: a, b, index lost
    assert unreachable_pages(tmp_path) == ["docs/a.md", "docs/b.md", "docs/index.md"]


def test_readme_is_short():
    n = len((ROOT / "README.md").read_text(encoding="utf-8").splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines, more than {README_MAX_LINES}: move detail into docs/"


@pytest.mark.parametrize("command", [MAIN_JOB, TEST_COMMAND])
def test_readme_opens_with_the_main_commands(command):
    head = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()[:README_HEAD_LINES]
    assert any(line.strip() == command for line in head), (
        f"`{command}` is not a line of the README's first {README_HEAD_LINES} lines")


def test_readme_test_command_is_the_one_ci_runs():
    assert TEST_COMMAND in (ROOT / ".ci" / "run").read_text(encoding="utf-8")


def test_every_docs_page_is_reachable_from_the_readme():
    missing = unreachable_pages()
    assert not missing, f"not linked from README.md or docs/index.md: {', '.join(missing)}"


def test_changelog_exists_and_the_readme_links_it():
    changelog = (ROOT / "CHANGELOG.md").resolve()
    assert changelog.is_file(), "CHANGELOG.md is missing"
    assert changelog in local_link_files(ROOT / "README.md"), "README.md does not link CHANGELOG.md"
