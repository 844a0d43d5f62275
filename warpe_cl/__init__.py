"""warpe-cl: laser travel time in icy and granular surfaces, by Monte Carlo in OpenCL.

A laser altimeter (BELA, GALA, ATLAS) records the whole return pulse; light that enters an icy
or granular surface comes back late, and the shape of the return carries the surface's
microtexture. warpe-cl walks rays through a compact slab (Fresnel interfaces, a Lambertian
floor) or a granular layer (no interface) with Henyey-Greenstein scattering, and tallies when
and where every ray leaves, by component: specular, back-and-forth direct, back-and-forth
diffuse, and multiple scattering.

Quick start::

    import warpe_cl
    cfg = warpe_cl.load_preset("presets/paper/gran_co2_thickness.yaml",
                               overrides={"simulation.photons": 1e4})
    warpe_cl.radiative_parameters(cfg)   # tau0, omega, extinction_per_m, n_eff, k_eff, ...
    ds = warpe_cl.simulate(cfg)          # xarray.Dataset: reflectance in ns-1 sr-1, fractions, ...

The command line does the same: ``warpe-cl run PRESET.yaml --out result.nc --plot result.png``.
"""
import sys as _sys
import types as _types

__all__ = ["load_preset", "simulate", "radiative_parameters", "open_database", "as_grid", "metrics",
           "invert", "__version__"]

#: The public names, each imported from its module on first use: ``import warpe_cl`` (the
#: start of every command) loads no NumPy, xarray or scipy, so that the command line catches a
#: Ctrl-C while they load (one line, exit 130) and the inversion's scipy imports
#: (scipy.special, 0.2 s) are paid only by ``warpe_cl.invert``.
_LAZY = {"load_preset": "config", "radiative_parameters": "radiative", "simulate": "api",
         "as_grid": "dataset", "open_database": "database", "metrics": "metrics",
         "invert": "inversion.invert"}


def __getattr__(name: str):
    """A public name of :data:`__all__` on first use (then kept)."""
    import importlib
    if name == "__version__":
        value = importlib.import_module(".io", __name__).package_version()
    elif name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    else:
        raise AttributeError(f"module 'warpe_cl' has no attribute {name!r}")
    if name != "invert":     # warpe_cl.invert stays looked up (docs: loaded on first use)
        globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(_types.ModuleType):
    """The package module: importing the submodule ``warpe_cl.metrics`` leaves
    ``warpe_cl.metrics`` the function of that name, as the public interface has it."""

    def __setattr__(self, name, value):
        if (name in _LAZY and isinstance(value, _types.ModuleType)
                and value.__name__ == f"{__name__}.{name}"):
            return
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package
