"""The host and the kernel agree on their shared layouts, named once in warpe_cl/params.py:
the walk kernel's parameters (engine.WALK_ARGS against cl/walk.cl), the layout macros
(params.kernel_layout against their uses in cl/), the tally shapes, and a kernel hash that
depends on the sources' contents only, not on where they are installed."""
from __future__ import annotations

import re
import shutil

import numpy as np
import pytest

from warpe_cl import params as P
from warpe_cl.device import assemble_source, every_program_file, kernel_dir, source_hash
from warpe_cl.engine import (WALK_ARGS, WALK_FILES, build_options, layout_options,
                             shared_options, walk_args, walk_source_hash)


def _code(text: str) -> str:
    """OpenCL C source without its comments."""
    text = re.sub(r"/\*.*?\*/", " ", text, flags=re.S)
    return re.sub(r"//[^\n]*", " ", text)


def _kernel_parameters(source: str, defined: set) -> list:
    """``(type, name)`` of each parameter of ``__kernel void walk(...)``, keeping the lines
    of the ``#ifdef`` blocks whose macro is in ``defined``."""
    code = _code(source)
    start = code.index("__kernel void walk(") + len("__kernel void walk(")
    end = re.compile(r"\)\s*\{").search(code, start).start()
    kept, stack = [], []
    for line in code[start:end].splitlines():
        directive = line.strip()
        if directive.startswith("#ifdef"):
            stack.append(directive.split()[1] in defined)
        elif directive.startswith("#ifndef"):
            stack.append(directive.split()[1] not in defined)
        elif directive.startswith("#endif"):
            stack.pop()
        elif all(stack):
            kept.append(line)
    assert not stack, "unbalanced #ifdef in the kernel's parameter list"
    out = []
    for decl in " ".join(kept).split(","):
        if decl.strip():
            ctype, name = re.fullmatch(r"\s*(.*?)\s*(\w+)\s*", decl).groups()
            out.append((_normal_type(ctype), name))
    return out


def _normal_type(ctype: str) -> str:
    """``const uint`` -> ``uint`` (a scalar's const is the kernel's business), spaces
    normalised around ``*``."""
    words = ctype.replace("*", " * ").split()
    if words[0] == "const" and "__global" not in words:
        words = words[1:]
    return " ".join(words)


@pytest.mark.parametrize("weighted,layered", [(False, False), (True, False), (False, True)])
@pytest.mark.parametrize("records", [False, True])
@pytest.mark.parametrize("nadir", [False, True])
def test_walk_arguments_match_the_kernel(weighted, records, layered, nadir):
    """engine.WALK_ARGS is cl/walk.cl's parameter list, in order, with its types, in every
    build (WARPE_WEIGHTED, WARPE_RECORD, WARPE_TEXTURE_LAYERS and WARPE_NADIR add
    parameters)."""
    source = (kernel_dir() / "walk.cl").read_text()
    defined = {m for m, on in (("WARPE_WEIGHTED", weighted), ("WARPE_RECORD", records),
                               ("WARPE_TEXTURE_LAYERS", layered), ("WARPE_NADIR", nadir)) if on}
    kernel = _kernel_parameters(source, defined)
    host = [(_normal_type(a.ctype), a.name)
            for a in walk_args(weighted, records, layered, nadir)]
    assert host == kernel


def test_walk_arguments_are_typed_and_named_once():
    names = [a.name for a in WALK_ARGS]
    assert len(names) == len(set(names))
    for a in WALK_ARGS:
        assert a.is_buffer or a.ctype in ("uint", "ulong", "int", "REAL"), a
        assert a.only in (None, "weighted", "records", "layers", "nadir"), a
        assert not (a.is_buffer and a.value is not None), f"{a.name}: buffers come per launch"
    # the scenario's values exist for a real WalkParams
    p = P.WalkParams(texture="slab", thickness=0.01, extinction=100.0, omega=0.9, g=0.8,
                     n=1.3, k=0.0, albedo=0.5, time_edges=np.linspace(0, 1, 5))
    for a in WALK_ARGS:
        if a.value is not None:
            assert np.isfinite(float(a.value(p))), a.name


LAYOUT_NAME = re.compile(r"\b(N_COMPONENTS|N_FATES|N_EMERGENCE|N_ITEM_STATS|N_RECORD_INT|"
                         r"N_RECORD_REAL|N_STATE_REAL|N_STATE_INT|COMPONENT_\w+|FATE_\w+|STAT_\w+|"
                         r"RECORD_\w+|STATE_\w+|TIME_BIN_\w+|N_LAYER_STATS|"
                         r"LSTAT_\w+|N_LAYER_REAL|LAYER_\w+|N_IFACE_REAL|IFACE_\w+|"
                         r"N_NADIR_ROWS|NADIR_ROW_\w+|NADIR_BATCHES|N_VIEW|VIEW_\w+|"
                         r"N_MIRROR|MIRROR_\w+|"
                         r"FIXED_SHIFT|FIXED_WORDS|MAX_WEIGHT)\b")


def test_layout_macros_come_from_params_only():
    """Every layout name the kernel uses is one of params.kernel_layout's macros, none is
    #defined in cl/ itself, and every one is used (every item_stats slot, record column and
    parked-ray column is written)."""
    layout = P.kernel_layout()
    code = "\n".join(_code((kernel_dir() / name).read_text())
                     for name in every_program_file(WALK_FILES))
    used = set(LAYOUT_NAME.findall(code))
    assert used <= set(layout), used - set(layout)
    assert set(layout) <= used, set(layout) - used
    for name in layout:
        assert not re.search(rf"#\s*define\s+{name}\b", code), f"{name} is defined in cl/"
    assert all(f"-D{k}={v}" in build_options("slab", "single", False) for k, v in layout.items())


def test_layout_values():
    layout = P.kernel_layout()
    assert layout["N_COMPONENTS"] == str(len(P.COMPONENTS)) == "4"
    assert [layout[f"COMPONENT_{c.upper()}"] for c in P.COMPONENTS] == ["0", "1", "2", "3"]
    assert layout["N_ITEM_STATS"] == str(len(P.ITEM_STATS)) == "8"
    assert layout["STAT_LOST_WEIGHTS"] == "7"
    assert layout["TIME_BIN_EARLY"] == "(-2)" and layout["TIME_BIN_LATE"] == "(-1)"
    assert float.fromhex(layout["MAX_WEIGHT"]) == P.MAX_WEIGHT
    assert P.RECORD_FIELDS.keys() == set(P.RECORD_INT_COLUMNS + P.RECORD_REAL_COLUMNS)


@pytest.mark.parametrize("weighted", [False, True])
def test_counts_have_the_tally_shapes(weighted):
    shapes = P.tally_shapes(7)
    c = P.Counts(n_time=7, weighted=weighted)
    for name, shape in shapes.items():
        value = getattr(c, name)
        if name in P.WEIGHT_TALLIES and not weighted:
            assert value is None
        else:
            assert value.shape == shape, name
    assert shapes["time_in_fov"] == (P.N_COMPONENTS, 7)
    assert shapes["angular"] == (P.N_COMPONENTS, P.N_EMERGENCE)
    assert shapes["fates"] == (P.N_FATES,)


def test_kernel_hash_does_not_depend_on_where_the_sources_are(tmp_path):
    """kernel_sha256 hashes the files' contents, the layout macros and the exact-division
    option: two copies of cl/ in different folders have the same hash (their assembled text
    differs by its #line paths); a changed file or option changes it."""
    a, b = tmp_path / "one" / "cl", tmp_path / "elsewhere" / "deeper" / "cl"
    shutil.copytree(kernel_dir(), a)
    shutil.copytree(kernel_dir(), b)
    assert assemble_source(WALK_FILES, a) != assemble_source(WALK_FILES, b)
    options = shared_options()
    assert source_hash(WALK_FILES, options, a) == source_hash(WALK_FILES, options, b)
    assert source_hash(WALK_FILES, options, a) == walk_source_hash()
    assert source_hash(WALK_FILES, options + ("-DWARPE_DOUBLE",), a) != walk_source_hash()
    assert source_hash(WALK_FILES, (), a) != walk_source_hash()
    assert source_hash(WALK_FILES, layout_options(), a) != walk_source_hash()   # exact division
    (b / "walk.cl").write_text((b / "walk.cl").read_text() + "\n")
    assert source_hash(WALK_FILES, options, b) != walk_source_hash()


def test_engine_records_the_kernel_hash(engine):
    from conftest import medium
    assert engine.kernel_hash in (None, walk_source_hash())
    engine.run(medium(), 100)
    assert engine.kernel_hash == walk_source_hash()
    assert re.fullmatch(r"[0-9a-f]{64}", engine.kernel_hash)


def test_emergence_table_is_the_hosts():
    """cl/tally_double.h's and cl/tally_single.h's COS_DEGREE tables are params.COS_DEGREE: the
    doubles exactly, and their roundings to float for the single walk (hex literals, so no
    compiler's decimal parsing enters); the host's emergence_bin follows the acos rule away
    from the edges, and puts an exit at an edge's cosine in the bin that starts there."""
    double_block, float_block = (
        re.search(r"COS_DEGREE\[N_EMERGENCE\] = \{(.*?)\};",
                  (kernel_dir() / f"tally_{p}.h").read_text(), re.S).group(1)
        for p in ("double", "single"))
    doubles = [float.fromhex(x) for x in re.findall(r"0x[0-9a-f.]+p[-+]\d+", double_block)]
    floats = [float.fromhex(x) for x in re.findall(r"0x[0-9a-f.]+p[-+]\d+", float_block)]
    assert doubles == list(P.COS_DEGREE)
    assert floats == [float(np.float32(c)) for c in P.COS_DEGREE]
    for deg in np.linspace(0.0, 90.0, 9001):
        if abs(deg - round(deg)) > 1e-6:
            assert P.emergence_bin(np.cos(np.radians(deg))) == min(int(deg), P.N_EMERGENCE - 1)
    assert [P.emergence_bin(c) for c in P.COS_DEGREE] == list(range(P.N_EMERGENCE))
    assert P.emergence_bin(1.5) == 0 and P.emergence_bin(-0.1) == P.N_EMERGENCE - 1
