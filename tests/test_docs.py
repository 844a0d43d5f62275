"""The documentation stands alone: every doc the package, tools, tests, presets, README and docs
cite is a file of this repository, every section cited next to it is a heading of that file,
and nothing points at a folder users never get.

A citation is a doc's name followed by section numbers and decision labels, in any of the
forms the code uses: ``docs/physics.md §5.5``, ``(docs/physics.md §3.4, §3.5)``,
``docs/physics.md §3–§4``, ``docs/physics.md §8 check 6``, ``docs/physics.md A12``. A section
``§N.M`` must be a Markdown heading numbered ``N.M`` in the cited file; a label ``A12`` a row
``| A12 |`` of a table there. A comment or docstring that wraps between the name and its
sections is read as one line. The three docs the code cites most, physics.md, interface.md and
instrument.md, are always written with their folder (``docs/physics.md``), except as the target
of a Markdown link between files of docs/.

Each check is one test that scans every file and lists every offending file and line in its
one failure message; test_each_check_lists_every_planted_violation shows that each still
fails, file by file and line by line, on violations planted in temporary files.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SELF = Path(__file__).resolve()
#: Where citations are looked for: the package, kernels, tools, tests, presets and docs, and
#: the README.
FOLDERS = ("warpe_cl", "cl", "tools", "tests", "presets", "docs")
TOP_FILES = ("README.md",)
SUFFIXES = {".py", ".cl", ".h", ".md", ".yaml", ".yml", ".cfg", ".toml", ".txt", ".sh"}
#: Docs that are always cited with their folder, docs/NAME.
UNIFORM = ("physics.md", "interface.md", "instrument.md")
#: Paths of the founders' private folders, which users never get (written split so that this
#: file does not match itself).
PRIVATE = ("shared" + "/docs", "shared" + "/bench", "shared" + "/seed", "../" + "shared")

#: A mention of a Markdown file: a bare name (physics.md) or a relative path (docs/walk.md).
MENTION = re.compile(r"(?<![\w./-])((?:[\w.-]+/)*[\w-]+\.md)\b")
#: One cited section or decision label.
TOKEN = r"(?:§\s?\d+(?:\.\d+)*|\bA\d+\b)"
#: The sections and labels right after a mention: "§3.4, §3.5", "§3–§4", "§5.5/§5.6", "A12".
CITATION = re.compile(r"^[\s:,()]*(" + TOKEN + r"(?:\s*(?:,|;|/|–|-|and|or)?\s*" + TOKEN + r")*)")
SECTION = re.compile(r"§\s?(\d+(?:\.\d+)*)|\b(A\d+)\b")
HEADING = re.compile(r"^#{1,6}\s+(\d+(?:\.\d+)*)\.?(?:\s|$)")
LABEL_ROW = re.compile(r"^\|\s*\**(A\d+)\**\s*\|")
#: A line break inside a comment or docstring, with the next line's comment leader.
CONTINUATION = re.compile(r"\s*\n\s*(?:\*(?!/)|#|//)?\s*")


def scanned_files() -> list:
    files = [REPO / name for name in TOP_FILES if (REPO / name).is_file()]
    for folder in FOLDERS:
        files += sorted(p for p in (REPO / folder).rglob("*")
                        if p.is_file() and p.suffix in SUFFIXES and "__pycache__" not in p.parts)
    return [p for p in files if p.resolve() != SELF]


FILES = scanned_files()


def _rel(path: Path) -> str:
    """A repository file's path from the root; any other file's (a test's own) as it is."""
    try:
        return path.relative_to(REPO).as_posix()
    except ValueError:
        return str(path)


def resolve(name: str, citing: Path) -> Path | None:
    """The file a mention ``name`` in ``citing`` means, or None if there is none.

    A path with a folder is read from the repository root (``docs/walk.md``) or, in a Markdown
    file, from that file's folder; a bare name is a file of docs/, the README at the root, or,
    in a Markdown file, a file next to it."""
    candidates = [REPO / name]
    if "/" not in name:
        candidates.append(REPO / "docs" / name)
    if citing.suffix == ".md":
        candidates.append(citing.parent / name)
    for candidate in candidates:
        if candidate.is_file():
            return candidate.resolve()
    return None


def citations(path: Path) -> list:
    """Every doc mention of ``path``: (line, name, [cited sections and labels], is a link)."""
    text = path.read_text(encoding="utf-8")
    out = []
    for match in MENTION.finditer(text):
        name = match.group(1)
        line = text.count("\n", 0, match.start()) + 1
        after = CONTINUATION.sub(" ", text[match.end(): match.end() + 240])
        cited = CITATION.match(after)
        sections = []
        if cited:
            sections = [a or b for a, b in SECTION.findall(cited.group(1))]
        link = text[max(0, match.start() - 2): match.start()] == "]("
        out.append((line, name, sections, link))
    return out


def anchors(doc: Path) -> set:
    """The numbered headings (``3.4``) and the decision labels (``A12``) of a Markdown file."""
    found = set()
    for line in doc.read_text(encoding="utf-8").splitlines():
        for pattern in (HEADING, LABEL_ROW):
            match = pattern.match(line)
            if match:
                found.add(match.group(1))
    return found


def _checks_sections(name: str) -> bool:
    """Sections are checked next to a path (docs/walk.md) and next to the bare names of UNIFORM;
    a bare walk.md in the code names the steps of docs/walk.md §3 as often as its headings."""
    return "/" in name or name in UNIFORM


def missing_citations(paths) -> list:
    """``FILE:LINE: ...`` for every cited doc that is not a file of the repository, and every
    cited section or decision label that its doc lacks, in ``paths``."""
    problems = []
    for path in paths:
        for line, name, sections, _ in citations(path):
            doc = resolve(name, path)
            if doc is None:
                problems.append(f"{_rel(path)}:{line}: {name} is not a file of the repository")
                continue
            if not _checks_sections(name) or doc.suffix != ".md":
                continue
            have = anchors(doc)
            for section in sections:
                if section not in have:
                    kind = "decision label" if section.startswith("A") else "heading"
                    problems.append(f"{_rel(path)}:{line}: {name} has no {kind} {section}")
    return problems


def private_paths(paths) -> list:
    """``FILE:LINE: PATH`` for every mention of a private folder in ``paths`` (every line, not
    only a file's first)."""
    problems = []
    for path in paths:
        for number, text in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            problems += [f"{_rel(path)}:{number}: {p}" for p in PRIVATE if p in text]
    return problems


def bare_citations(paths) -> list:
    """``FILE:LINE: NAME`` for every citation of a UNIFORM doc without its folder in ``paths``
    (a Markdown link between files of docs/ excepted)."""
    return [f"{_rel(path)}:{line}: {name}" for path in paths
            for line, name, _, link in citations(path)
            if name in UNIFORM and not (link and path.suffix == ".md")]


def _report(problems: list, what: str) -> str:
    return f"{len(problems)} {what}:\n" + "\n".join(problems)


def test_cited_docs_and_sections_exist():
    problems = missing_citations(FILES)
    if problems:
        pytest.fail(_report(problems, "citations of a missing doc, heading or label"))


def test_no_private_paths():
    problems = private_paths(FILES)
    if problems:
        pytest.fail(_report(problems, "mentions of a folder users never get (cite the "
                            "repository's docs, docs/physics.md, docs/interface.md, "
                            "docs/instrument.md, or tools instead)"))


def test_citations_name_the_docs_folder():
    problems = bare_citations(FILES)
    if problems:
        pytest.fail(_report(problems, "citations without their folder (write docs/NAME)"))


def test_each_check_lists_every_planted_violation(tmp_path):
    """A check that stopped at the first offence, or at the first file, would hide the rest:
    each scanner reports every file and line of violations planted in temporary files, and
    nothing in a clean one."""
    one, two, clean = tmp_path / "one.py", tmp_path / "two.md", tmp_path / "clean.h"
    one.write_text("# docs/physics.md §3.4 holds\n"
                   "# docs/no_such_doc.md\n"
                   "# docs/physics.md §99.9 and A999\n"
                   "# physics.md §3.4, " + "shared" + "/docs/x\n", encoding="utf-8")
    two.write_text("See interface.md §5.\n\nAlso ../" + "shared" + "/bench, twice: "
                   + "shared" + "/seed.\n[the physics](physics.md)\n", encoding="utf-8")
    clean.write_text("/* docs/physics.md §3.4, docs/interface.md §5 */\n", encoding="utf-8")
    o, t = str(one), str(two)
    assert missing_citations([one, two, clean]) == [
        f"{o}:2: docs/no_such_doc.md is not a file of the repository",
        f"{o}:3: docs/physics.md has no heading 99.9",
        f"{o}:3: docs/physics.md has no decision label A999"]
    assert private_paths([one, two, clean]) == [
        f"{o}:4: " + "shared" + "/docs",
        f"{t}:3: " + "shared" + "/bench", f"{t}:3: " + "shared" + "/seed",
        f"{t}:3: ../" + "shared"]
    # the bare name in a .py file and in prose of a .md file; a link between docs is allowed
    assert bare_citations([one, two, clean]) == [f"{o}:4: physics.md", f"{t}:1: interface.md"]
    for found in (missing_citations, private_paths, bare_citations):
        assert found([clean]) == []


def test_the_scanner_finds_the_citations(tmp_path):
    """A scanner that silently found nothing would pass every test above."""
    every = [(path, c) for path in FILES for c in citations(path)]
    physics = [c for _, c in every if c[1].endswith("physics.md")]
    assert len(physics) >= 50
    assert sum(len(c[2]) for c in physics) >= 60
    assert any(c[1].endswith("interface.md") and "5" in c[2] for _, c in every)
    assert any(c[1].endswith("instrument.md") and "3.4" in c[2] for _, c in every)
    # the forms the code uses, and a comment wrapped between a name and its sections
    sample = tmp_path / "sample.h"
    sample.write_text("/* (docs/physics.md §3.4, §3.5) docs/physics.md §3–§4;\n"
                      " * docs/physics.md\n * §3.5, A12) docs/physics.md §8 check 6 */\n",
                      encoding="utf-8")
    got = [c[2] for c in citations(sample)]
    assert got == [["3.4", "3.5"], ["3", "4"], ["3.5", "A12"], ["8"]]


def test_the_cited_docs_have_the_sections_the_code_relies_on():
    """The numbering that the code's citations rely on, in the docs themselves."""
    physics = anchors(REPO / "docs" / "physics.md")
    assert {str(i) for i in range(1, 11)} <= physics
    assert {"3.4", "3.5", "3.6", "4.2", "4.4", "4.6", "5.5", "6.1", "7.3"} <= physics
    assert {f"8.{i}" for i in range(1, 10)} <= physics
    assert {f"A{i}" for i in range(1, 16)} <= physics
    assert {"2", "3", "4", "5"} <= anchors(REPO / "docs" / "interface.md")
    instrument = anchors(REPO / "docs" / "instrument.md")
    assert {"1", "2.1", "2.2", "2.3", "3", "3.0", "3.4", "3.7.5", "3.9", "5"} <= instrument
