"""Shared fixtures: one OpenCL engine for the whole session, and helpers to build media."""
from __future__ import annotations

import numpy as np
import pytest

from warpe_cl.params import WalkParams

LOG_EDGES = 1e-6 * 10 ** (np.arange(0, 221) / 20)   # 1e-6 .. 1e5 ns, 20 bins per decade


@pytest.fixture(scope="session")
def engine():
    """The OpenCL engine on the device `auto` picks (a usable device is required: the
    kernels are what this project is)."""
    from warpe_cl.engine import Engine
    return Engine()


@pytest.fixture(scope="session")
def selftest(engine):
    """The self-test program (single and double precision), for the kernel building blocks."""
    from warpe_cl.device import SELFTEST_FILES, build_program
    progs = {"single": build_program(engine.device, SELFTEST_FILES, ())[0]}
    if engine.info.fp64:
        progs["double"] = build_program(engine.device, SELFTEST_FILES, ("-DWARPE_DOUBLE",))[0]
    return progs


def medium(**kw) -> WalkParams:
    """A WalkParams with readable defaults (slab, 10 mm, tau0 = 1, omega = 0.9, ...)."""
    base = dict(texture="slab", thickness=0.01, extinction=100.0, omega=0.9, g=0.8, n=1.3,
                k=1e-4, albedo=0.5, time_edges=LOG_EDGES, bottom_interface="fresnel", seed=7)
    base.update(kw)
    return WalkParams(**base)
