"""The package's import graph has no circles and imports at module top.

Every module of ``warpe_cl/`` is parsed with :mod:`ast` (imports inside
functions included) and the graph of imports between ``warpe_cl`` modules
is built from it. The tests fail on any cycle, listing each one, and on
any function-level import, listing every offender in one message:

* a ``warpe_cl`` module may be imported inside a function only in
  ``cli.py``, whose verbs import their modules lazily for start-up time;
* a third-party module may be imported inside a function only when it is
  a heavy, optional dependency named in :data:`HEAVY`; the standard
  library is not checked (``fcntl``: POSIX only, ``importlib`` in the
  package's lazy ``__getattr__``).

Run as a script (``python tests/test_imports.py``) to print the graph's
cycles and offenders without pytest.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

PACKAGE = "warpe_cl"
ROOT = Path(__file__).resolve().parent.parent / PACKAGE

#: Modules whose function bodies may import ``warpe_cl`` modules lazily.
LAZY_MODULES = frozenset({"warpe_cl.cli"})

#: Heavy or optional third-party top-level packages that may be imported
#: inside functions: they cost start-up time or may be absent.
HEAVY = frozenset({
    "pyopencl",     # OpenCL runtime: absent on machines without a device
    "matplotlib",   # figures only
    "dask",         # distributed sweeps only
    "distributed",  # distributed sweeps only
    "h5py",         # NetCDF4 back end, optional
    "scipy",        # a few fits and special functions only
    "xarray",       # heavy import; only where Datasets are built or read
    "yaml",         # only where config files are read
    "netCDF4",      # optional NetCDF4 back end
    "h5netcdf",     # optional NetCDF4 back end
    "emcee",        # optional sampler
    "PIL",          # figures only
    "psutil",       # optional machine probes
    "tqdm",         # optional progress bars
})


def module_name(path: Path) -> str:
    """Return the dotted module name of a file under :data:`ROOT`.

    Parameters
    ----------
    path : Path
        A ``.py`` file inside the package.

    Returns
    -------
    str
        Its dotted name; a package's ``__init__`` is the package itself.
    """
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def modules() -> dict[str, Path]:
    """Return every module of the package by dotted name.

    Returns
    -------
    dict of str to Path
        Dotted name to source file.
    """
    return {module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def _resolve(name: str, is_package: bool, node: ast.ImportFrom) -> str:
    """Return the absolute module a relative ``from`` import names."""
    if node.level == 0:
        return node.module or ""
    base = name.split(".")
    if not is_package:
        base = base[:-1]
    if node.level > 1:
        base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _targets(name, is_package, node, known):
    """Yield the absolute modules an import node names.

    ``from pkg import sub`` names the module ``pkg.sub`` where that is a
    module of the package, else ``pkg`` itself.
    """
    if isinstance(node, ast.Import):
        for alias in node.names:
            yield alias.name
        return
    mod = _resolve(name, is_package, node)
    for alias in node.names:
        sub = f"{mod}.{alias.name}"
        yield sub if sub in known else mod


def _owner(target: str, known) -> str:
    """Return the package module ``target`` lives in (longest known prefix)."""
    parts = target.split(".")
    while parts:
        cand = ".".join(parts)
        if cand in known:
            return cand
        parts.pop()
    return target


def scan():
    """Parse every module and collect its imports.

    Returns
    -------
    graph : dict of str to set of str
        Each package module to the package modules it imports, anywhere.
    lazy : list of tuple
        ``(module, line, imported, kind)`` for every import inside a
        function, ``kind`` being ``"package"`` or ``"third-party"``.
    """
    known = modules()
    graph: dict[str, set[str]] = {m: set() for m in known}
    lazy = []
    for name, path in known.items():
        is_package = path.name == "__init__.py"
        tree = ast.parse(path.read_text(), filename=str(path))
        parents = {}
        for node in ast.walk(tree):
            for child in ast.iter_child_nodes(node):
                parents[child] = node
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            in_function = False
            up = parents.get(node)
            while up is not None:
                if isinstance(up, (ast.FunctionDef, ast.AsyncFunctionDef,
                                   ast.Lambda)):
                    in_function = True
                    break
                up = parents.get(up)
            for target in _targets(name, is_package, node, known):
                top = target.split(".")[0]
                if top == PACKAGE:
                    dest = _owner(target, known)
                    if dest != name:
                        graph[name].add(dest)
                    if in_function:
                        lazy.append((name, node.lineno, dest, "package"))
                elif in_function and top not in sys.stdlib_module_names:
                    lazy.append((name, node.lineno, top, "third-party"))
    return graph, lazy


def cycles(graph):
    """Return the graph's circles, one per strongly connected component.

    Parameters
    ----------
    graph : dict of str to set of str
        Module to the modules it imports.

    Returns
    -------
    list of list of str
        For each component with more than one module (or a self-import),
        its modules, sorted, the component's size first in the report.
    """
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1 or v in graph.get(v, ()):
                out.append(sorted(comp))

    sys.setrecursionlimit(max(10000, sys.getrecursionlimit()))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _path_in(graph, comp):
    """Return one closed path through a component, for the report."""
    members = set(comp)
    start = comp[0]
    # breadth-first back to start from each successor
    for first in sorted(graph[start] & members):
        prev = {first: None}
        queue = [first]
        while queue:
            v = queue.pop(0)
            if v == start:
                path = []
                while v is not None:
                    path.append(v)
                    v = prev[v]
                return [start] + path[::-1]
            for w in sorted(graph[v] & members):
                if w not in prev:
                    prev[w] = v
                    queue.append(w)
    return comp


def offenders(lazy):
    """Return the function-level imports the rules forbid.

    Parameters
    ----------
    lazy : list of tuple
        As returned by :func:`scan`.

    Returns
    -------
    list of str
        ``module:line imports target`` for each offender.
    """
    bad = []
    for module, line, target, kind in sorted(set(lazy)):
        if kind == "package" and module in LAZY_MODULES:
            continue
        if kind == "third-party" and target in HEAVY:
            continue
        bad.append(f"{module}:{line} imports {target} inside a function")
    bad = list(dict.fromkeys(bad))
    return bad


def test_no_import_cycles():
    """No circle of imports between the package's modules."""
    graph, _ = scan()
    found = cycles(graph)
    report = [
        f"{len(c)} modules: " + " -> ".join(_path_in(graph, c))
        + "\n    members: " + ", ".join(c)
        for c in found
    ]
    assert not found, "import cycles:\n  " + "\n  ".join(report)


def test_no_function_level_imports():
    """Imports sit at module top, but for cli's verbs and heavy packages."""
    _, lazy = scan()
    bad = offenders(lazy)
    assert not bad, (
        f"{len(bad)} function-level imports:\n  " + "\n  ".join(bad))


if __name__ == "__main__":
    g, lz = scan()
    for c in cycles(g):
        print(f"cycle ({len(c)}):", " -> ".join(_path_in(g, c)))
        print("    members:", ", ".join(c))
    for b in offenders(lz):
        print(b)
