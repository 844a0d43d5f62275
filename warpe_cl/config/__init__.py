"""Presets: the schema table, YAML loading, ``--set`` overrides, validation and sweep grids.

A preset is a YAML file (or a plain dict of the same shape, docs/interface.md §3). Every key it
may hold is one row of :data:`SCHEMA`; that table is the single source of the key names,
kinds, units, defaults, limits and help texts. It drives validation, the defaults, the
resolved YAML written by :meth:`Config.to_yaml` and the reference table of
:func:`schema_markdown`.

>>> cfg = load_preset({"medium": {"texture": "granular", "thickness": "100 mm",
...                               "radiative": {"tau0": 1.0, "omega": 0.9, "n": 1.3}}})
>>> cfg.get("medium.thickness")          # metres
0.1
>>> cfg.get("simulation.fov.scattering")  # degrees
12.0
>>> cfg.get("simulation.photons")
1000000

Canonical units in :attr:`Config.data` and :meth:`Config.get`: lengths in metres, times in
nanoseconds, angles in degrees. Every mistake raises :class:`~warpe_cl.errors.ConfigError`
with one line naming the file, the key, the value and what is allowed.

=====================  ==================================================================
module                 what it does
=====================  ==================================================================
``schema``             :class:`Field` and the table :data:`SCHEMA`
``validate``           scalar checks and their messages, did-you-mean, the YAML reader (refuses
                       duplicate keys); shared with the instrument presets
``keys``               dotted keys (``medium.inclusions[0].grain_size``) and ``--set`` overrides
``check``              the pass over a whole preset: sections, materials, time bins, the medium
``bins``               time-bin edges
``preset``             :class:`Config` and :func:`load_preset`
``grid``               sweep grids: :func:`load_grid` (the one point expander,
                       ``expand_points``, is in ``keys``)
``instrument_fields``  the instrument presets' table and loading, a preset's
                       ``instrument:`` block resolved, :func:`field_for` for both tables
``docs``               docs/config.md from the table
=====================  ==================================================================
"""
from __future__ import annotations

from .bins import time_edges
from .docs import REFERENCE_PATH, reference_markdown, schema_markdown
from .grid import Grid, load_grid
from .instrument_fields import field_for
from .preset import Config, load_preset
from .schema import (DEFAULTS, FIELDS, MAX_FLIGHTS, MAX_PHOTONS, MAX_TIME_BINS,
                     MIN_ROULETTE_SURVIVAL, QUANTITY_KINDS, SCALAR_KINDS, SCHEMA, Field)

__all__ = ["Field", "SCHEMA", "FIELDS", "Config", "load_preset", "time_edges",
           "schema_markdown", "reference_markdown", "Grid", "load_grid", "MAX_PHOTONS",
           "field_for"]
