"""A surface family of a design study: a sweep database, its parameter space, the derived
quantities it identifies and the points around each node at which the expected samples are
differentiated (docs/design.md §2).

The derivative of the model along an axis at a node is taken through the inversion's own
interpolation (:meth:`warpe_cl.inversion.space.Space.surface`), which is piecewise smooth with
kinks at the nodes: it is the mean of the two one-sided slopes, each over a quarter of the cell
on its side (one-sided at the grid's edges).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..database import database_folder, load_result
from ..errors import ConfigError
from ..inversion.derived import (EDGE_BAND, grid_values, prior_grid, quantiles,
                                 values_at, quantities)
from ..inversion.options import check_complete, dataset_header, header
from ..inversion.space import Space

#: The fraction of the cell on each side of a node over which a one-sided slope is taken.
STEP_FRACTION = 0.25
#: The derived quantities a study reports (docs/inversion.md §6.1), where the database varies
#: them: the extinction coefficient E, the optical thickness τ0 and the mean delay ⟨t⟩.
DERIVED = ("extinction_per_m", "tau0", "mean_delay_ns")
#: Symbols of the derived quantities in tables and figures.
SYMBOLS = {"extinction_per_m": "E", "tau0": "tau0", "mean_delay_ns": "<t>"}


@dataclass
class Derived:
    """One derived quantity of a family: its :class:`~warpe_cl.inversion.derived.Quantity`
    and the width of its prior 95 % interval in its comparison coordinate (ln of the value,
    or the value)."""
    quantity: object
    prior_width: float


@dataclass
class NodePoints:
    """The surfaces around one node: the node's own, and per axis the points a step below and
    above (None beyond the grid) with their steps in the interpolation coordinate."""
    index: tuple
    point: dict
    surface: object
    below: list = field(default_factory=list)     # per axis: (surface, step, point) or None
    above: list = field(default_factory=list)
    derived_below: list = field(default_factory=list)     # per axis: values of the quantities
    derived_above: list = field(default_factory=list)
    derived_here: list = field(default_factory=list)


class Family:
    """A surface family: a complete sweep database and what the study needs of it.

    Parameters
    ----------
    name : str
        The family's label.
    database : path or xarray.Dataset
        A ``warpe-cl sweep`` folder, a sweep file, or a Dataset.
    source : str, optional
        The database's name in messages (default: the path).
    """

    def __init__(self, name: str, database, source: str | None = None):
        self.name = name
        if hasattr(database, "dims"):
            db, self.source = database, source or "<database>"
            check_complete(dataset_header(db, self.source))
        else:
            path = Path(database)
            self.source = source or str(path)
            if path.suffix == ".nc" and not path.is_file():
                path = database_folder(path)[0]
            if not path.exists():
                raise ConfigError("no such database (a `warpe-cl sweep` folder or a sweep "
                                  "file); give its path, or a preset: to sweep it first",
                                  key=self.source)
            head = header(path, self.source)
            if head is not None:
                check_complete(head)
            db = load_result(path)
            if head is None:
                check_complete(dataset_header(db, self.source))
        self.db = db
        self.space = Space(db, source=self.source)
        self.axes = self.space.axes
        if not self.axes:
            raise ConfigError("sweeps no numeric key: nothing to design for",
                              key=self.source)
        self.wavelength = self.space.wavelength
        self.derived = self._derived()
        self.nodes = [self._points(index) for index in np.ndindex(self.space.nodes.shape)]

    @property
    def parameters(self) -> list:
        """The names of the swept keys, then of the derived quantities."""
        return [a.key for a in self.axes] + [d.quantity.name for d in self.derived]

    def _derived(self) -> list:
        """The quantities of :data:`DERIVED` that vary over the grid, with their prior
        widths (the 2.5 % to 97.5 % points of their prior, as the inversion's)."""
        found = [q for q in quantities(self.space, self.db, tail_after_ns=math.inf)
                 if q.name in DERIVED]
        if not found:
            return []
        coords, weights = prior_grid(self.space)
        values, w = grid_values(self.space, found, coords, weights, math.inf)
        out = []
        for k, q in enumerate(found):
            low, high = quantiles(q.coord(values[k]).ravel(), w.ravel(),
                                   (EDGE_BAND, 1.0 - EDGE_BAND))
            out.append(Derived(q, float(high - low)))
        return out

    def _points(self, index: tuple) -> NodePoints:
        """The node ``index``'s surface and those a step either side of it along each axis
        (module docstring)."""
        space = self.space
        point = {a.key: float(a.values[i]) for a, i in zip(self.axes, index)}
        found = [d.quantity for d in self.derived]
        here = NodePoints(index, point, space.nodes[index].surface,
                          derived_here=values_at(space, found, point, math.inf) if found
                          else [])
        for j, axis in enumerate(self.axes):
            x = axis.nodes
            i = index[j]
            for side, target, values in ((-1, here.below, here.derived_below),
                                         (+1, here.above, here.derived_above)):
                k = i + side
                if k < 0 or k >= x.size:
                    target.append(None)
                    values.append(None)
                    continue
                step = STEP_FRACTION * abs(x[k] - x[i])
                moved = dict(point)
                moved[axis.key] = float(axis.value(x[i] + side * step))
                target.append((space.surface(moved), step, moved))
                values.append(values_at(space, found, moved, math.inf) if found else [])
        return here

    def neighbours(self, index: tuple) -> list:
        """The indices of the nodes one step away along one axis."""
        out = []
        for j in range(len(index)):
            for side in (-1, 1):
                k = index[j] + side
                if 0 <= k < self.space.nodes.shape[j]:
                    out.append(index[:j] + (k,) + index[j + 1:])
        return out

    def prior_width(self, axis) -> float:
        """The width of an axis' prior 95 % interval in its interpolation coordinate (0.95 of
        its range, the prior being uniform in it)."""
        return 0.95 * float(axis.nodes[-1] - axis.nodes[0])


def slope(here, below, above) -> np.ndarray | float:
    """The mean of the one-sided slopes of a quantity at a node (module docstring).

    Parameters
    ----------
    here : array or float
        Its value at the node.
    below, above : tuple or None
        Its value a step below and above and the step (in the interpolation coordinate),
        ``(value, step, ...)``; None beyond the grid.

    Returns
    -------
    array or float
        The derivative per unit of the interpolation coordinate.
    """
    parts = []
    if below is not None:
        parts.append((here - below[0]) / below[1])
    if above is not None:
        parts.append((above[0] - here) / above[1])
    if not parts:
        return 0.0 * here
    return sum(parts) / len(parts)
