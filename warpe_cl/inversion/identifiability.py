"""How well the data constrain a key: the width-ratio thresholds of docs/inversion.md §6.2,
shared by the inversion's outputs and its printed summary (which loads nothing heavy).
"""
from __future__ import annotations

#: A swept key or derived quantity is ``constrained`` when its posterior 95 % interval is
#: narrower than this fraction of the prior's 95 % interval, in the prior's coordinate (a
#: uniform posterior over half the prior range: 1 bit, ln 2 = 0.69 nats of information).
CONSTRAINED = 0.5
#: ... and ``weakly constrained`` below this fraction, ``not constrained`` from it on.
WEAKLY = 0.9


def verdict(ratio: float) -> str:
    """How well a width ratio (posterior 95 % width / the prior's, in the prior's coordinate)
    constrains: ``constrained`` (< :data:`CONSTRAINED`), ``weakly constrained`` (<
    :data:`WEAKLY`) or ``not constrained`` (also for NaN)."""
    return ("constrained" if ratio < CONSTRAINED else
            "weakly constrained" if ratio < WEAKLY else "not constrained")
