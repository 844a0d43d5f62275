"""The two forms of the kernels' built-ins (cl/lanes_*.h): OpenCL's select(), fmax, clamp, fabs
and rint, which warpe_cl.engine.driver_options keeps for Intel's CPU runtime (-DWARPE_BUILTINS),
and the ?: operator with comparisons, selects and bits that every other driver gets. They differ
in speed only: every tally and every ray's record is the same bits, on this device, in the
vector form of the walk and in the GPUs' one-lane form."""
import numpy as np
import pytest

from conftest import walk_with_options
from warpe_cl.engine import driver_options, kernel_key
from warpe_cl.params import WalkParams

EDGES = np.geomspace(1e-3, 10.0, 41)


def _params(texture: str) -> WalkParams:
    """A medium that reaches every branch of the walk: Fresnel faces (slab), the floor, the
    nadir estimate with its roulette; a few hundred scatterings per ray at most."""
    return WalkParams(texture=texture, thickness=0.02, extinction=1000.0, omega=0.99, g=0.7,
                      n=1.3, k=1e-5, albedo=0.3, time_edges=EDGES, nadir=True,
                      nadir_roulette=0.1, view_zenith=10.0)


def test_driver_options_keep_the_builtins_for_intel_cpu_only():
    from warpe_cl.device import DeviceInfo
    intel = DeviceInfo(0, 0, "Intel(R) OpenCL", "OpenCL 3.1", "cpu", "cpu", "x", 2, True)
    pocl = DeviceInfo(1, 0, "Portable Computing Language", "OpenCL 3.0 PoCL", "cpu", "cpu",
                      "x", 2, True, 8, 4)
    gpu = DeviceInfo(0, 0, "Intel(R) OpenCL Graphics", "OpenCL 3.0", "gpu", "gpu", "x", 24, True)
    assert driver_options(intel) == ("-DWARPE_BUILTINS",)
    assert driver_options(pocl) == () and driver_options(gpu) == ()


# one vector width per precision: the lanes' built-ins and their inline forms are the same
# code at every width, which tests/test_kernel_blocks.py checks bit for bit at 1, 8 and 16
@pytest.mark.parametrize("lanes,precision", [(1, "single"), (8, "single"), (4, "double")])
@pytest.mark.parametrize("texture", ["granular", "slab"])
def test_builtins_and_inline_forms_give_the_same_bits(engine, texture, lanes, precision):
    from warpe_cl.engine import build_options
    if precision == "double" and not engine.info.fp64:
        pytest.skip("no double precision on this device")
    params = _params(texture)
    structure = (texture, precision, True, lanes, False, True)
    own = engine.run(params, 2000, records=True, lanes=lanes, qualified=True,
                     precision=precision)
    key = kernel_key(*structure)
    assert engine.program_options(key) == build_options(*structure) + driver_options(engine.info)
    other = (() if driver_options(engine.info) else ("-DWARPE_BUILTINS",))
    swapped = walk_with_options(engine, structure, build_options(*structure) + other, params,
                                2000, records=True, lanes=lanes, qualified=True,
                                precision=precision)
    assert own.scattering_events > 40_000                  # 20 scatterings a ray and more
    assert np.count_nonzero(own.records["nadir"]) > 1000
    assert own.same_as(swapped)
    assert np.array_equal(own.records["nadir"], swapped.records["nadir"])
    assert np.array_equal(own.nadir_sum, swapped.nadir_sum)
