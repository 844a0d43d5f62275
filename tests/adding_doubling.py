"""Independent adding-doubling reference for the diffuse reflectance at nadir (test helper).

This module is a helper of the tests, not a test file. It computes, with Scott Prahl's
adding-doubling code iadpython (pip package ``iadpython``, the ``test`` extra of setup.cfg;
never a runtime dependency), the diffuse bidirectional reflectance of a plane-parallel slab at
normal incidence and normal emergence: the quantity the Monte Carlo next-event (nadir)
estimator measures. See :func:`nadir_brdf` for the exact convention and how it is taken from
iadpython's matrices.

Two things of iadpython 0.5.3 are worked around, openly:

* its ``radau()`` builds Radau weights from ``numpy.poly1d`` derivatives, which lose all
  accuracy above about 24 points (the weights no longer sum to 1: -3.5e-5 at 32 points, -0.09
  at 40, -0.5 at 64). :func:`radau` below computes the same rule (same nodes, same order,
  last node at the upper end) from the Jacobi roots of scipy, exact to 1e-14 at 400 points,
  and equal to iadpython's to 2e-9 for n <= 20. The quadrature is handed to iadpython through
  the attributes ``Sample.nu`` and ``Sample.twonuw`` that it caches itself, built exactly
  as ``Sample.update_quadrature`` builds them for normal incidence.
* ``hg_legendre`` (the delta-M Henyey-Greenstein redistribution matrices) is a pure-Python
  O(N^3) loop (0.6 s at N = 128, 5 s at N = 256); its result depends on g, n and N only, so
  it is cached per (g, n, N) and handed over through ``Sample.hp`` / ``Sample.hm`` likewise.

Run ``python tests/adding_doubling.py`` for a table on the grid omega in {0.5, 0.9, 0.99},
tau0 in {0.5, 2, 10}, g in {0, 0.5, 0.8}, n in {1, 1.31}.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import scipy.special

#: Quadrature points used by default. The delta-M series of iadpython keeps N Legendre terms of
#: the phase function, and the backscatter value of a truncated Henyey-Greenstein series
#: converges like N g^N. On the grid of :func:`table` (n = 1 and 1.31) extended to g = 0.9, the
#: largest relative change against N = 256 is, for N = 64 / 96 / 128 / 192:
#: g <= 0.5: 5e-5 / 2e-5 / 3e-5 / 2e-5; g = 0.8: 8e-5 / 2e-5 / 2e-5 / 2e-5;
#: g = 0.9: 1.1e-1 / 5.6e-3 / 2.4e-4 / 2e-5 (the floor of ~3e-5 is the O(d) error of
#: iadpython's infinitesimal-generator starting layer). N = 128 is < 0.1 % for g <= 0.9 and
#: costs ~0.02 s a call at n = 1, ~0.09 s at n > 1 (plus 0.6 s once per (g, n) for the
#: redistribution matrices).
DEFAULT_QUAD_PTS = 128


def hg_phase(cos_theta: float, g: float) -> float:
    """Henyey-Greenstein phase function normalised to 1 over the sphere, in sr^-1:
    p = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos_theta)^(3/2))."""
    return (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * cos_theta) ** 1.5)


def radau(n: int, a: float, b: float) -> tuple:
    """n-point Gauss-Radau rule on [a, b] with the node b included, as iadpython orders it.

    Same rule as ``iadpython.radau(n, a, b)`` (nodes increasing, the last one = b, exact for
    polynomials of degree 2 n - 2), computed stably: on [-1, 1] with the fixed node -1, the
    free nodes are the roots of the Jacobi polynomial P_{n-1}^{(0,1)}, the weights are
    2 / n^2 at -1 and (1 - x) / (n^2 P_{n-1}(x)^2) elsewhere; then x -> b at x = -1."""
    x = np.empty(n)
    w = np.empty(n)
    x[0] = -1.0
    w[0] = 2.0 / n**2
    if n > 1:
        xi, _ = scipy.special.roots_jacobi(n - 1, 0.0, 1.0)
        x[1:] = xi
        w[1:] = (1.0 - xi) / (n**2 * scipy.special.eval_legendre(n - 1, xi) ** 2)
    x = x * 0.5 * (a - b) + 0.5 * (a + b)
    w = w * 0.5 * (b - a)
    return np.flip(x), np.flip(w)


def _frozen(array) -> np.ndarray:
    array = np.array(array, dtype=float)
    array.setflags(write=False)
    return array


@lru_cache(maxsize=None)
def _quadrature(n: float, quad_pts: int) -> tuple:
    """(nu, twonuw) as ``iadpython.Sample.update_quadrature`` makes them at normal incidence:
    Radau on [0, 1] if n = 1; else Gauss on [0, nu_c] and Radau on [nu_c, 1], quad_pts / 2
    points each, nu_c the cosine of the critical angle inside the slab. nu are cosines inside
    the slab, the last one is 1; twonuw = 2 nu w."""
    import iadpython
    if n == 1.0:
        nu, w = radau(quad_pts, 0.0, 1.0)
    else:
        nu_c = iadpython.cos_critical(n, 1.0)
        nu1, w1 = iadpython.gauss(quad_pts // 2, a=0.0, b=nu_c)
        nu2, w2 = radau(quad_pts // 2, nu_c, 1.0)
        nu, w = np.append(nu1, nu2), np.append(w1, w2)
    assert nu[-1] == 1.0
    return _frozen(nu), _frozen(2.0 * nu * w)


@lru_cache(maxsize=None)
def _redistribution(g: float, n: float, quad_pts: int) -> tuple:
    """iadpython's delta-M HG redistribution matrices (hp, hm) on the quadrature above."""
    import iadpython
    sample = _sample(0.0, 1.0, g, n, quad_pts, redistribution=False)
    hp, hm = iadpython.hg_legendre(sample)
    return _frozen(hp), _frozen(hm)


def _sample(a: float, b: float, g: float, n: float, quad_pts: int, redistribution=True,
            n_below: float = 1.0, slides: tuple | None = None):
    """An ``iadpython.Sample`` with the accurate quadrature: no slide above, and below none
    (``n_below`` 1: a slab in vacuum) or a black slide of index ``n_below`` (an index-matched
    black substrate); or, given ``slides`` = ((n_above, b_above), (n_below, b_below)), those
    clear slides (index, absorption optical thickness along the normal) above and below."""
    import iadpython
    if slides is not None:
        (n_top, b_top), (n_bottom, b_bottom) = slides
        sample = iadpython.Sample(a=a, b=b, g=g, n=n, n_above=n_top, n_below=n_bottom,
                                  quad_pts=quad_pts)
        sample.b_above, sample.b_below = b_top, b_bottom
    else:
        sample = iadpython.Sample(a=a, b=b, g=g, n=n, n_above=1.0, n_below=n_below,
                                  quad_pts=quad_pts)
    if slides is None and n_below != 1.0:
        # iadpython's medium below is a slide and then air: a black substrate of the slab's
        # index is a slide of that index that absorbs everything (absorbance 1e3 along the
        # normal: exp(-1e3) comes back)
        sample.b_below = 1e3
    sample.nu, sample.twonuw = _quadrature(n, quad_pts)
    if redistribution:
        sample.hp, sample.hm = _redistribution(g, n, quad_pts)
    return sample


def _r11(a: float, b: float, g: float, n: float, quad_pts: int, n_below: float = 1.0,
         slides: tuple | None = None) -> float:
    """Element R[-1, -1] (nu = 1 in, nu = 1 out) of iadpython's reflection matrix R03 of the
    whole slab (boundaries included), for light incident from above."""
    R03, _, _, _ = _sample(a, b, g, n, quad_pts, n_below=n_below, slides=slides).rt_matrices()
    return float(R03[-1, -1])


def nadir_brdf(omega: float, tau0: float, g: float, n: float = 1.0,
               quad_pts: int = DEFAULT_QUAD_PTS, matched_below: bool = False,
               slides: tuple | None = None) -> float:
    """Diffuse bidirectional reflectance at nadir of a slab in vacuum, by adding-doubling.

    Convention (that of the Monte Carlo next-event estimator at nadir):

    * slab of optical depth ``tau0`` (extinction, absorption + scattering), single-scattering
      albedo ``omega``, Henyey-Greenstein phase function of asymmetry ``g`` normalised to 1
      over the sphere, p(Theta) = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos Theta)^(3/2));
    * real refractive index ``n``: n = 1, no interfaces; n > 1, a Fresnel interface with
      vacuum at the top and at the bottom (a slab in vacuum, no slides); nothing below (the
      transmitted light is lost);
    * collimated beam at normal incidence (mu0 = 1); returned: f(mu0 = 1, mu = 1) in sr^-1,
      the reflected radiance at exact normal emergence over the incident irradiance, i.e.
      dP/dOmega at nadir per incident photon, the solid angle measured in vacuum;
    * diffuse part only: the specular reflection of the top face and the unscattered light
      reflected by the bottom face (delta functions at nadir) are excluded; everything that
      scattered at least once is kept, with all the Fresnel internal reflections.

    How it is taken from iadpython: ``Sample(a=omega, b=tau0, g=g, n=n, n_above=1,
    n_below=1)`` gives ``rt_matrices()``, whose first matrix R03 is the reflection operator
    of the whole slab in Prahl's normalisation: on the quadrature cosines nu_i *inside* the
    slab, the reflected radiance is L(nu_i) = sum_j R_ij L_in(nu_j) 2 nu_j w_j (the identity
    operator is diag(1 / (2 nu_j w_j)), and the collimated total reflectance is
    UR1 = sum_i 2 nu_i w_i R_i,last). A collimated irradiance E at nu_0 = 1 is the radiance
    E delta(nu - 1) / (2 pi), so L(nu_i) = R_i,last E / pi; leaving the slab, 2 nu dnu inside
    becomes 2 mu dmu / n^2 outside (Snell; nu = mu = 1 at nadir), so the radiance in vacuum is
    divided by n^2 (the same n^2 as in iadpython's URU). Hence

        f = (R03[-1, -1] - R03_0[-1, -1]) / (pi n^2),

    where [-1, -1] is nu_i = nu_j = 1 (last Radau node) and R03_0 is the same slab with no
    scattering (a = 0, b = iadpython's delta-M thickness (1 - omega g^N) tau0): the diagonal
    delta terms of the unscattered light (top-face specular reflection, bottom-face reflection
    of the direct beam, and their multiple reflections) cancel exactly. iadpython uses the
    delta-M method with N = quad_pts Legendre terms; the forward peak it removes (a fraction
    g^N of each scattering, 1e-6 at g = 0.9, N = 128) is counted as unscattered and dropped.
    The cancellation leaves an absolute round-off of ~1e-11 sr^-1 (measured 6e-12 at n = 1.31,
    tau0 = 1, N = 128), negligible against any physical f (1e-4 and up).

    Checked (tests/test_adding_doubling.py): n = 1 isotropic conservative semi-infinite,
    Chandrasekhar's H(1)^2 / (8 pi) = 0.33643; n = 1 and 1.31, omega -> 0, finite and
    semi-infinite slabs: :func:`single_scattering_nadir_brdf` (which for n = 1 is
    omega p(pi) (1 - exp(-2 tau0)) / 2).

    Parameters
    ----------
    omega : float
        Single-scattering albedo, 0 <= omega <= 1.
    tau0 : float
        Optical depth of the slab (> 0; ``np.inf`` for a semi-infinite one, which converges
        slowly at omega = 1: use a large finite tau0 there, e.g. 1e5).
    g : float
        Henyey-Greenstein asymmetry, -1 < g < 1.
    n : float
        Real refractive index of the slab, >= 1 (vacuum outside).
    quad_pts : int
        Quadrature points (even, >= 4); the default suits g <= 0.9 to < 0.1 %.
    matched_below : bool
        False: a slab in vacuum (a Fresnel bottom face); True: the slab on a black medium of
        its own index (no bottom face: warpe-cl's slab with ``bottom_interface: none`` over a
        black floor).
    slides : ((n_above, b_above), (n_below, b_below)), optional
        Clear slides in optical contact above and below the slab, in vacuum: real index and
        absorption optical thickness along the normal (iadpython's ``n_above``, ``b_above``,
        ``n_below``, ``b_below``; its boundary matrices take every reflection inside a slide,
        :func:`iadpython.absorbing_glass_RT`). A stack of warpe-cl: a non-scattering slab
        above the scattering one and one below, over a vacuum gap and a black floor. The
        radiance leaves the slab's index for vacuum through the slides, whose n^2 cancel:
        f is still R / (pi n^2). Overrides ``matched_below``.

    Returns
    -------
    float
        f(mu0 = 1, mu = 1) in sr^-1.
    """
    if not 0.0 <= omega <= 1.0:
        raise ValueError(f"omega must be in [0, 1], got {omega}")
    if not tau0 >= 0.0:
        raise ValueError(f"tau0 must be >= 0, got {tau0}")
    if not -1.0 < g < 1.0:
        raise ValueError(f"g must be in (-1, 1), got {g}")
    if not n >= 1.0:
        raise ValueError(f"n must be >= 1, got {n}")
    if quad_pts < 4 or quad_pts % 2:
        raise ValueError(f"quad_pts must be even and >= 4, got {quad_pts}")
    n, g, quad_pts = float(n), float(g), int(quad_pts)
    if omega == 0.0 or tau0 == 0.0:
        return 0.0
    below = n if matched_below else 1.0
    r_all = _r11(omega, tau0, g, n, quad_pts, below, slides)
    scaled_tau0 = (1.0 - omega * g**quad_pts) * tau0      # Sample.b_delta_M()
    r_unscattered = _r11(0.0, scaled_tau0, 0.0, n, quad_pts, below, slides)
    return (r_all - r_unscattered) / (math.pi * n * n)


def single_scattering_nadir_brdf(omega: float, tau0: float, g: float, n: float = 1.0) -> float:
    """Exact first-order (single-scattering) part of :func:`nadir_brdf`, in sr^-1.

    At normal incidence every unscattered path is vertical, so the single-scattering nadir
    reflectance of the slab in vacuum is a one-dimensional sum. With r = ((n - 1) / (n + 1))^2
    and t = 1 - r the Fresnel reflectance and transmittance at normal incidence, T = exp(-tau0)
    and K = 1 / (1 - r^2 T^2) (the bounces between the faces):

    * direct beam inside, per incident photon: down D(z) = t K e^-z, up U(z) = t r K T^2 e^z;
    * source of once-scattered radiance along the vertical: up omega (D p(pi) + U p(0)),
      down omega (D p(0) + U p(pi));
    * A_up = omega t K [p(pi) (1 - T^2) / 2 + r T^2 tau0 p(0)] reaches the top going up,
      A_dn = omega t K T [tau0 p(0) + r p(pi) (1 - T^2) / 2] reaches the bottom going down;
    * f = t K (A_up + r T A_dn) / n^2 (exit through the top, n^2 law of radiance).

    For n = 1: omega p(pi) (1 - exp(-2 tau0)) / 2; for tau0 -> inf: omega t^2 p(pi) / (2 n^2).
    """
    r = ((n - 1.0) / (n + 1.0)) ** 2
    t = 1.0 - r
    p_back, p_fwd = hg_phase(-1.0, g), hg_phase(1.0, g)
    T = math.exp(-tau0)
    K = 1.0 / (1.0 - (r * T) ** 2)
    tau_T2 = 0.0 if math.isinf(tau0) else tau0 * T * T
    tau_T = 0.0 if math.isinf(tau0) else tau0 * T
    a_up = omega * t * K * (p_back * (1.0 - T * T) / 2.0 + r * tau_T2 * p_fwd)
    a_dn = omega * t * K * (tau_T * p_fwd + r * T * p_back * (1.0 - T * T) / 2.0)
    return t * K * (a_up + r * T * a_dn) / (n * n)


GRID = dict(omega=(0.5, 0.9, 0.99), tau0=(0.5, 2.0, 10.0), g=(0.0, 0.5, 0.8), n=(1.0, 1.31))


def table(quad_pts: int = DEFAULT_QUAD_PTS, grid: dict = GRID) -> list:
    """Rows (n, g, omega, tau0, f_AD, f_single) of :func:`nadir_brdf` on ``grid`` (sr^-1)."""
    rows = []
    for n in grid["n"]:
        for g in grid["g"]:
            for omega in grid["omega"]:
                for tau0 in grid["tau0"]:
                    rows.append((n, g, omega, tau0, nadir_brdf(omega, tau0, g, n, quad_pts),
                                 single_scattering_nadir_brdf(omega, tau0, g, n)))
    return rows


def print_table(quad_pts: int = DEFAULT_QUAD_PTS) -> None:
    """Print :func:`table`: the adding-doubling value and its single-scattering part."""
    import iadpython
    print(f"diffuse nadir BRDF f(1, 1) [sr^-1], iadpython {iadpython.__version__}, "
          f"quad_pts = {quad_pts}")
    print(f"{'n':>5} {'g':>4} {'omega':>6} {'tau0':>5} {'f_AD':>12} {'f_single':>12}")
    for n, g, omega, tau0, f, f1 in table(quad_pts):
        print(f"{n:5.2f} {g:4.1f} {omega:6.2f} {tau0:5.1f} {f:12.6e} {f1:12.6e}")


if __name__ == "__main__":
    print_table()
