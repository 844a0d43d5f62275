"""log L through a database against log L of a directly simulated surface at the same point:
whether the database's stated error (:mod:`.emulator`) holds (docs/inversion.md §4.3,
tools/studies/emulator_check.py).
"""
from __future__ import annotations

import numpy as np

from .counting import CountShots
from .emulator import DirectSurface, Emulator
from .likelihood import Shots
from .posterior import Problem


def agreement(space, forward, time_ns, samples, point: dict, surface, v=None,
              emulator=None) -> dict:
    """log L at ``point`` three ways, the nuisances fitted each time.

    Parameters
    ----------
    space : Space
        The database.
    forward : Forward
        The instrument.
    time_ns, samples : arrays
        The recorded shots: sample times (ns) and samples (shots × samples, mV), or
        histogram bin starts (ns) and counts (shots × bins) of a photon-counting receiver.
    point : dict
        Free key -> value (axis units) where ``surface`` was simulated.
    surface : SurfaceResponse
        The directly simulated surface at ``point``, with its standard errors.
    v : float, optional
        The broadening nuisance, ns² (None: profiled).
    emulator : Emulator, optional
        The database's error model of ``space`` and ``forward``; give the same one to every
        call on a database, so that its node waveforms and leave-one-out errors are computed
        once (default: a new one).

    Returns
    -------
    dict
        ``database`` (log L with the database's error integrated out), ``plain`` (the
        database taken as exact), ``direct`` (the direct surface, its own Monte Carlo error
        integrated out), ``sigma`` and ``offset`` (the database's stated error and expected
        offset of log L at this point, :func:`~.emulator.shared_error`), ``sigma_direct``,
        and ``z`` = (plain − direct − offset) / √(σ² + σ_direct²): about N(0, 1) where the
        stated error holds.
    """
    u = space.coords_of(point)[[space.axes.index(a) for a in space.free_axes]]
    out = {}
    direct = DirectSurface(surface, forward, space.free_axes)
    emulator = emulator if emulator is not None else Emulator(space, forward)
    for name, where, error in (("plain", space, None), ("database", space, emulator),
                               ("direct", direct, direct)):
        shots = (CountShots if forward.counting else Shots)(time_ns, samples, forward)
        problem = Problem(where, forward, shots, v=v, emulator=error)
        e = problem.evaluate(u)
        out[name] = e.loglike
        if name == "database":
            out["sigma"], out["offset"] = e.fit.emulator_sd, e.fit.emulator_offset
        if name == "direct":
            out["sigma_direct"] = e.fit.emulator_sd
    total = float(np.hypot(out["sigma"], out["sigma_direct"]))
    out["z"] = (out["plain"] - out["direct"] - out["offset"]) / total if total > 0 else 0.0
    return out
