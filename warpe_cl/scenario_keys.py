"""Scenario keys as the output files write them, and read back.

A scenario's 64-bit key (:func:`warpe_cl.api.scenario_key`, docs/walk.md §2) is written as
16 hexadecimal digits (the ``scenario_key`` attribute or variable of a result, the sweep
manifest) and read back by the instrument chain, which keys each shot's noise by it. Both
directions live here, below :mod:`warpe_cl.api`, :mod:`warpe_cl.sweep` and
:mod:`warpe_cl.instrument`, which all use them.

>>> format_key(255)
'00000000000000ff'
>>> parse_key(format_key(2**64 - 1)) == 2**64 - 1
True
"""
from __future__ import annotations

import numpy as np

__all__ = ["format_key", "parse_key"]


def format_key(key: int) -> str:
    """A scenario key as the 16 hexadecimal digits the output files carry.

    Parameters
    ----------
    key : int
        The key, in [0, 2**64).

    Returns
    -------
    str
        Zero-padded lower-case hexadecimal.
    """
    return f"{int(key):016x}"


def parse_key(value) -> int:
    """A scenario key as read back from a file.

    Parameters
    ----------
    value : str, bytes or int
        The hex string :func:`format_key` writes (text or bytes, as NetCDF gives it back),
        or, from older files, an integer.

    Returns
    -------
    int
        The key.
    """
    if isinstance(value, (bytes, np.bytes_)):
        value = value.decode()
    if isinstance(value, str):
        return int(value, 16)
    return int(value)
