"""The examples in the package's docstrings run, as written, against the installed package."""
from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import warpe_cl

#: Every module of the package; ``__main__`` runs the command line on import.
MODULES = sorted(m.name for m in pkgutil.walk_packages(warpe_cl.__path__, "warpe_cl.")
                 if not m.name.endswith("__main__"))
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _examples(name: str) -> list:
    module = importlib.import_module(name)
    return [t for t in doctest.DocTestFinder().find(module, name) if t.examples]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    for test in _examples(name):
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"


def test_the_examples_are_found():
    # A finder that silently found nothing would pass every test above.
    found = {name: sum(len(t.examples) for t in _examples(name)) for name in MODULES}
    assert "warpe_cl.config" in found and "warpe_cl.units" in found and "warpe_cl.api" in found
    assert found["warpe_cl.units"] >= 5 and found["warpe_cl.api"] >= 2
    assert sum(found.values()) >= 30
