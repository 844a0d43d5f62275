"""The paper presets load, validate and run; the captions' cheap qualitative claims hold.

Trend assertions compare two scenarios' means with a margin of 5 standard errors of their
difference (false alarm ~6e-7 each)."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from warpe_cl import simulate
from warpe_cl.api import scenario_key, walk_params
from warpe_cl.catalog import presets_dir
from warpe_cl.config import load_preset
from warpe_cl.errors import WarpeWarning
from warpe_cl.params import FATES

PAPER = sorted((presets_dir() / "paper").glob("*.yaml"))
REQUIRED = {"slab_h2o_thickness", "slab_co2_thickness", "slab_h2o_co2_thickness",
            "slab_h2o_co2_grainsize", "slab_h2o_co2_compacity", "slab_h2o_s_compacity",
            "slab_h2o_void_compacity", "gran_co2_thickness", "gran_h2o_grainsize",
            "gran_h2o_compacity", "fov_numerical", "bela_cases"}


def test_every_required_paper_preset_exists():
    assert REQUIRED <= {p.stem for p in PAPER}


@pytest.mark.parametrize("path", PAPER, ids=[p.stem for p in PAPER])
def test_paper_preset_runs_at_a_tiny_photon_count(path, engine):
    photons = 200
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", WarpeWarning)   # e.g. 200 um grains in a 1 mm layer
        cfg = load_preset(path, overrides={"simulation.photons": photons})
        ds = simulate(cfg, progress=False)
        points = cfg.sweep_points()
        if len(points) > 1:
            assert ds.sizes["scenario"] == len(points)
        for i, (point, pcfg) in enumerate(points):
            params, _ = walk_params(pcfg, scenario_key(point, pcfg))
            c = engine.run(params, photons)
            # The kernel's integer counts: every launched ray has exactly one fate, and every
            # ray that left through the top is tallied in exactly one component.
            assert c.fates.sum() == photons, c.fates
            exits = c.fates[FATES.index("specular")] + c.fates[FATES.index("escaped")]
            assert c.total.sum() == exits, (c.total, c.fates)
            # The file's fractions are those counts over the rays launched.
            frac = ds["fate_fraction"].values[i] if len(points) > 1 else ds["fate_fraction"].values
            np.testing.assert_array_equal(frac, c.fates / photons)


def _exit_stats(engine, preset, overrides, n=20_000):
    """(escaped fraction, its sigma, mean exit time of escaped rays in ns, its sigma)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", WarpeWarning)
        cfg = load_preset(presets_dir() / "paper" / f"{preset}.yaml", overrides=overrides)
        params, _ = walk_params(cfg.sweep_points()[0][1])
    c = engine.run(params, n, records=True)
    escaped = c.records["fate"] == 1
    f = escaped.mean()
    t = c.records["time_ns"][escaped]
    return f, np.sqrt(f * (1 - f) / n), t.mean(), t.std() / np.sqrt(len(t))


def _assert_greater(a, sa, b, sb):
    assert a - b > 5 * np.hypot(sa, sb), (a, sa, b, sb)


def test_slab_smaller_impurities_scatter_more_and_return_sooner(engine):
    """Slab_eau_co2_10_diam: smaller d: more rays leave, and sooner."""
    small = _exit_stats(engine, "slab_h2o_co2_grainsize",
                        {"sweep.medium.inclusions[0].grain_size": ["25 um"]})
    large = _exit_stats(engine, "slab_h2o_co2_grainsize",
                        {"sweep.medium.inclusions[0].grain_size": ["500 um"]})
    _assert_greater(small[0], small[1], large[0], large[1])
    _assert_greater(large[2], large[3], small[2], small[3])


@pytest.mark.parametrize("preset", ["slab_h2o_co2_compacity", "slab_h2o_s_compacity"])
def test_slab_more_impurities_brighter_and_shorter(engine, preset):
    """Slab_water_*_porosity: smaller compacity: more scattering, larger reflectance, shorter
    mean travel time."""
    dirty = _exit_stats(engine, preset, {"sweep.medium.compacity": [0.9]})
    clean = _exit_stats(engine, preset, {"sweep.medium.compacity": [0.999]})
    _assert_greater(dirty[0], dirty[1], clean[0], clean[1])
    _assert_greater(clean[2], clean[3], dirty[2], dirty[3])


def test_sulfur_impurities_are_dimmer_than_co2(engine):
    """Sulfur absorbs more than CO2: lower reflectance at the same compacity."""
    co2 = _exit_stats(engine, "slab_h2o_co2_compacity", {"sweep.medium.compacity": [0.9]})
    sulfur = _exit_stats(engine, "slab_h2o_s_compacity", {"sweep.medium.compacity": [0.9]})
    _assert_greater(co2[0], co2[1], sulfur[0], sulfur[1])


def test_granular_smaller_grains_return_sooner_and_brighter(engine):
    """Gran_eau_diam."""
    small = _exit_stats(engine, "gran_h2o_grainsize",
                        {"sweep.medium.inclusions[0].grain_size": ["25 um"]}, n=5000)
    large = _exit_stats(engine, "gran_h2o_grainsize",
                        {"sweep.medium.inclusions[0].grain_size": ["400 um"]}, n=5000)
    _assert_greater(small[0], small[1], large[0], large[1])
    _assert_greater(large[2], large[3], small[2], small[3])


def test_porous_granular_medium_returns_later(engine):
    """Gran_water_porosity: compacity 0.1 (very porous) returns later than 0.9."""
    porous = _exit_stats(engine, "gran_h2o_compacity", {"sweep.medium.compacity": [0.1]}, n=5000)
    packed = _exit_stats(engine, "gran_h2o_compacity", {"sweep.medium.compacity": [0.9]}, n=5000)
    _assert_greater(porous[2], porous[3], packed[2], packed[3])


def test_water_slab_hides_its_floor_co2_slab_shows_it(engine):
    """Slab_h2o_h / Slab_co2_h: at 1000 mm the CO2 slab returns a BF direct and the water slab
    (tau0 = 15) returns none in 2e5 rays (expected 3e-10 of them)."""
    n = 200_000
    for preset, visible in (("slab_co2_thickness", True), ("slab_h2o_thickness", False)):
        cfg = load_preset(presets_dir() / "paper" / f"{preset}.yaml",
                          overrides={"sweep.medium.thickness": ["1000 mm"]})
        params, _ = walk_params(cfg.sweep_points()[0][1])
        c = engine.run(params, n)
        assert (c.total[1] > 0.02 * n) if visible else (c.total[1] == 0)
