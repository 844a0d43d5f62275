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
from .config import load_preset
from .radiative import radiative_parameters
from .api import simulate
from .io import package_version, as_grid
from .database import open_database
from .metrics import metrics

__version__ = package_version()
__all__ = ["load_preset", "simulate", "radiative_parameters", "open_database", "as_grid", "metrics",
           "invert", "__version__"]


def __getattr__(name: str):
    """``warpe_cl.invert`` on first use: the inversion pulls in scipy.signal and scipy.stats
    (0.65 s of imports), which a walk never needs."""
    if name == "invert":
        from .inversion.invert import invert
        return invert
    raise AttributeError(f"module 'warpe_cl' has no attribute {name!r}")
