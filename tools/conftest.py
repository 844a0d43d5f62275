"""The fixtures and helpers of tests/conftest.py, for the tests of the benchmarks (tools/bench/)
and of the validation studies (tools/studies/). They are outside the default ``pytest`` run
(setup.cfg: ``testpaths = tests``); run them on demand from the repository root::

    python -m pytest tools/bench
    python -m pytest tools/studies          # -m "not slow" leaves out the slow ones

tests/conftest.py is loaded under a name of its own (``warpe_cl_test_helpers``: this file is
the ``conftest`` module of such a run), and everything it defines is re-exported here, so that
``from conftest import TOOLS`` and the ``engine`` fixture work as in tests/. It also gives
``BENCH`` and ``STUDIES``, the two folders of tools/.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path


def _load_test_helpers():
    """tests/conftest.py as the module ``warpe_cl_test_helpers`` (loaded once per session)."""
    name = "warpe_cl_test_helpers"
    if name not in sys.modules:
        path = Path(__file__).resolve().parents[1] / "tests" / "conftest.py"
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


_helpers = _load_test_helpers()
globals().update({k: v for k, v in vars(_helpers).items() if not k.startswith("__")})

#: The benchmarks and the validation studies.
BENCH = TOOLS / "bench"  # noqa: F821 - TOOLS comes from tests/conftest.py
STUDIES = TOOLS / "studies"  # noqa: F821
