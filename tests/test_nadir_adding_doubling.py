"""The total nadir BRDF of the next-event estimator against adding-doubling (iadpython, in the
``test`` extra; tests/adding_doubling.py) at normal incidence and emergence (docs/walk.md §8.4):
a layer of index 1 over a black floor, and a slab of index 1.31 with a Fresnel top on a black
floor in optical contact (adding-doubling: a black medium of the slab's index below) or over a
vacuum gap, whose lower face is a Fresnel mirror (adding-doubling: vacuum below; the
estimator follows the mirror paths, walk.md §8.5).

The adding-doubling value is the diffuse BRDF f(1, 1) (every path with at least one
scattering, all Fresnel reflections at the faces included); the Monte Carlo's is the
time-integrated ``bf_diffuse`` + ``scattering`` estimate (A = 0: only ``scattering``). The
tolerance is 5 sigma of the estimator's batch error; the reference's own error (< 3e-5
relative at 128 quadrature points, tests/test_adding_doubling.py) is far below it.
"""
from __future__ import annotations

import numpy as np
import pytest

from adding_doubling import nadir_brdf
from warpe_cl.nadir import _batch_error
from warpe_cl.params import NADIR_ROWS, WalkParams, fixed_to_float

EDGES = np.concatenate([[0.0], np.logspace(-4, 4, 33)])
#: (omega, tau0, g, n, bottom): n = 1 walks a granular layer (no interface), n = 1.31 a slab
#: with a Fresnel top, on a black floor in contact (none) or over a vacuum gap (fresnel)
GRID = [(0.9, 2.0, 0.5, 1.0, "none"), (0.99, 10.0, 0.0, 1.0, "none"),
        (0.5, 0.5, 0.8, 1.0, "none"),
        (0.9, 0.5, 0.8, 1.31, "none"), (0.99, 2.0, 0.5, 1.31, "none"),
        (0.5, 10.0, 0.0, 1.31, "none"), (0.99, 10.0, 0.8, 1.31, "none"),
        (0.9, 0.5, 0.8, 1.31, "fresnel"), (0.99, 2.0, 0.5, 1.31, "fresnel"),
        (0.5, 10.0, 0.0, 1.31, "fresnel"), (0.99, 10.0, 0.8, 1.31, "fresnel")]


@pytest.mark.parametrize("omega,tau0,g,n,bottom", GRID)
def test_total_nadir_brdf_matches_adding_doubling(engine, omega, tau0, g, n, bottom):
    h = 0.01
    texture = "granular" if n == 1.0 else "slab"
    p = WalkParams(texture=texture, thickness=h, extinction=tau0 / h, omega=omega, g=g, n=n,
                   k=0.0, albedo=0.0, time_edges=EDGES,
                   bottom_interface=bottom,
                   nadir=True, nadir_roulette=0.1)
    counts = engine.run(p, 200_000)
    rows = [NADIR_ROWS.index("bf_diffuse"), NADIR_ROWS.index("scattering")]
    sums = fixed_to_float(counts.nadir_sum)[:, rows, :].sum(axis=(1, 2))     # per batch
    value = sums.sum() / counts.photons
    err = float(_batch_error(sums, counts.nadir_batch_photons))
    expected = nadir_brdf(omega, tau0, g, n, matched_below=bottom == "none")
    # 5 sigma of the estimator; the 1e4 ns last edge: no ray is cut by the time cap
    assert counts.fates[-1] == 0
    assert abs(value - expected) < 5.0 * err, (value, expected, err, (value - expected) / err)
    assert err < 0.02 * expected          # sharp: 5 sigma within 10 %


def test_estimate_over_a_mirror_and_none_under_a_buried_one():
    """A slab over a vacuum gap (the presets' default) gets the nadir estimate with its mirror
    paths (the mirror_table rows of a thin slab: up and down paths and the gap's round
    trips); a stack with a Fresnel contact below its top has mirrors between layers whose
    paths are not followed, and its result says so instead of estimating."""
    import warpe_cl
    from warpe_cl.api import walk_params
    from warpe_cl.nadir import mirror_table
    from warpe_cl.params import MIRROR_KINDS
    cfg = warpe_cl.load_preset("radiative/slab_co2_1m", overrides={"simulation.photons": 200})
    ds = warpe_cl.simulate(cfg, device="numpy", progress=False)
    assert "nadir_reflectance" in ds and ds.attrs["nadir_estimator"].startswith("next-event")
    thin = WalkParams(texture="slab", thickness=0.01, extinction=50.0, omega=0.9, g=0.7,
                      n=1.4, k=0.0, albedo=0.6, time_edges=EDGES, bottom_interface="fresnel")
    kinds = [MIRROR_KINDS[int(k)] for k in mirror_table(thin)[:, 0]]
    assert kinds == ["up", "up", "down", "down", "down", "gap", "gap"]
    stack = warpe_cl.load_preset("layers/frost_over_ice", overrides={"simulation.photons": 200})
    params, _ = walk_params(stack)
    assert not params.nadir
    assert "mirror" in warpe_cl.api._nadir_attrs(stack, params)["nadir_estimator"]
