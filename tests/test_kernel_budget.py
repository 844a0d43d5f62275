"""The kernel's size budget (docs/walk.md §5.1): no kernel file (cl/*.cl, cl/*.h) over 800
lines, no kernel function over 120 lines, and at most 4 conditional preprocessor lines
(#if, #ifdef, #ifndef, #elif, #else) per 100 lines of a file. Pure text parsing: every
offender is listed at once."""
from __future__ import annotations

import re
from pathlib import Path

from warpe_cl.device import every_program_file, kernel_dir, program_files
from warpe_cl.engine import WALK_FILES

MAX_FILE_LINES = 800
MAX_FUNCTION_LINES = 120
MAX_CONDITIONALS_PER_100 = 4

CONDITIONAL = re.compile(r"^\s*#\s*(if|ifdef|ifndef|elif|else)\b")
NAME = re.compile(r"(\w+)\s*\(")


def kernel_files() -> list:
    folder = kernel_dir()
    return sorted(list(folder.glob("*.cl")) + list(folder.glob("*.h")))


def lines_of(path: Path) -> list:
    return path.read_text().splitlines()


def conditional_lines(lines: list) -> int:
    return sum(1 for line in lines if CONDITIONAL.match(line))


def functions(lines: list) -> list:
    """(name, first line, length) of every function defined with its body's braces at column 0:
    the signature starts at the last line at column 0 before the `{` that is neither a
    preprocessor line nor a comment (a kernel's arguments may have #ifdef lines between)."""
    out = []
    for i, line in enumerate(lines):
        if line.rstrip() != "{":
            continue
        start = i - 1
        while start > 0 and (not lines[start][:1].strip() or lines[start].startswith("#")
                             or not re.match(r"[A-Za-z_]", lines[start])):
            start -= 1
        end = next(j for j in range(i + 1, len(lines)) if lines[j].rstrip() == "}")
        m = NAME.search(lines[start])
        out.append((m.group(1) if m else lines[start].strip(), start + 1, end - start + 1))
    return out


def budget_offenders() -> list:
    offenders = []
    for path in kernel_files():
        lines = lines_of(path)
        n = len(lines)
        if n > MAX_FILE_LINES:
            offenders.append(f"{path.name}: {n} lines (at most {MAX_FILE_LINES})")
        for name, first, length in functions(lines):
            if length > MAX_FUNCTION_LINES:
                offenders.append(f"{path.name}:{first}: {name}() is {length} lines "
                                 f"(at most {MAX_FUNCTION_LINES})")
        c = conditional_lines(lines)
        if c * 100 > MAX_CONDITIONALS_PER_100 * n:
            offenders.append(f"{path.name}: {c} conditional lines in {n} "
                             f"(at most {MAX_CONDITIONALS_PER_100} per 100)")
    return offenders


def test_kernel_files_keep_the_budget():
    offenders = budget_offenders()
    assert not offenders, "over the kernel budget (docs/walk.md §5.1):\n" + "\n".join(offenders)


def test_every_walk_file_is_budgeted():
    """Every file that a build of the walk compiles (the parts of every precision, lane width
    and driver that the host picks, warpe_cl/device.py program_files) is a kernel file the
    budget reads, and none is exempt: there is no list of exemptions."""
    names = {path.name for path in kernel_files()}
    assert set(every_program_file(WALK_FILES)) <= names
    assert "CONDITIONAL_CEILING" not in globals()


def test_the_host_picks_the_switches_files():
    """Precision, lane width and built-ins choose files, not #if blocks (docs/walk.md §5.1)."""
    single = program_files(WALK_FILES, ("-DWARPE_LANES=1",))
    double = program_files(WALK_FILES, ("-DWARPE_LANES=16", "-DWARPE_DOUBLE",
                                        "-DWARPE_BUILTINS"))
    assert single[:6] == ("real.h", "real_single.h", "lanes.h", "lanes_scalar.h",
                          "lanes_inline.h", "philox.h")
    assert double[:8] == ("real.h", "real_double.h", "lanes.h", "lanes_16.h", "lanes_vector.h",
                          "lanes_vector_builtins.h", "lanes_builtins.h", "philox.h")
    assert program_files(WALK_FILES) == single
    for files in (single, double):
        assert files[-1] == "walk.cl" and len(set(files)) == len(files)
    for switch in ("WARPE_DOUBLE", "WARPE_BUILTINS", "WARPE_LANES =", "WARPE_LANES >"):
        users = [n for n in every_program_file(WALK_FILES)
                 if re.search(rf"^\s*#\s*(if|ifdef|ifndef|elif).*{switch}",
                              text_of(n), re.M)]
        allowed = {"WARPE_DOUBLE": {"nadir.h", "walk.cl"}, "WARPE_LANES >": {"philox.h"},
                   "WARPE_BUILTINS": {"score_single.h"}}.get(switch, set())
        assert set(users) <= allowed, (switch, users)


def text_of(name: str) -> str:
    return (kernel_dir() / name).read_text()


def test_the_parser_finds_the_walk_kernel():
    lines = lines_of(kernel_dir() / "walk.cl")
    found = {name: length for name, _, length in functions(lines)}
    assert "walk" in found and "walk_event" in found and "no_rays" in found
    assert 60 < found["walk"] <= MAX_FUNCTION_LINES


def test_every_offender_is_listed(tmp_path, monkeypatch):
    """Two files over budget at once: both named in one message."""
    body = "\n".join(["#ifdef A", "#else", "#endif"] * 3)
    long_fn = "inline void f(void)\n{\n" + "    ;\n" * 130 + "}\n"
    (tmp_path / "a.h").write_text(body + "\n")
    (tmp_path / "b.cl").write_text(long_fn + "x\n" * 800)
    monkeypatch.setitem(globals(), "kernel_dir", lambda: tmp_path)
    offenders = budget_offenders()
    assert any(o.startswith("a.h: 6 conditional lines") for o in offenders), offenders
    assert any(o.startswith("b.cl: ") and "lines (at most 800)" in o for o in offenders)
    assert any("f() is 133 lines" in o for o in offenders), offenders
