"""What ``warpe-cl invert`` pays before it inverts: the forward model convolves with the real
FFTs of scipy.fft, the same bits as scipy.signal.fftconvolve, without importing scipy.signal
(0.7 to 1.0 s of every ``warpe-cl invert`` on 2 cores for an instrument with a Gaussian
filter, which needs nothing else of it); the p-value is scipy.special's chi2 survival
function, the same bits as scipy.stats.chi2.sf, without importing scipy.stats (0.45 to
0.65 s). And what each model evaluation of the inversion saves without moving a bit: the
photons' FFTs taken once per point for every pulse width, the line search's shorter steps
taken for the shots still pending only, the fit's model table read again by the database
error."""
from __future__ import annotations

import subprocess
import sys

import numpy as np

from warpe_cl.inversion.forward import Spectrum


def test_a_spectrums_convolution_is_fftconvolves_bits():
    from scipy.signal import fftconvolve
    rng = np.random.default_rng(3)
    sizes = [(1, 7), (7, 1), (1, 1), (2, 2), (3001, 257), (220, 3000)]
    sizes += [tuple(rng.integers(1, 4000, 2)) for _ in range(200)]
    for n, m in sizes:
        a, b = rng.random(n), rng.random(m)
        assert np.array_equal(Spectrum(a).convolve(Spectrum(b)),
                              fftconvolve(a, b, mode="full")), (n, m)


def test_the_p_value_is_scipy_stats_chi2_sf():
    from scipy.special import chdtrc
    from scipy.stats import chi2
    rng = np.random.default_rng(4)
    for dof in list(rng.integers(1, 50_000, 300)) + [1, 2, 7]:
        for x in (0.0, 1e-300, float(rng.random() * 3 * dof), 1e300, np.inf):
            assert chdtrc(dof, x) == chi2.sf(x, dof), (dof, x)


def test_the_inversion_leaves_scipy_signal_and_stats_alone():
    code = ("import sys\n"
            "import warpe_cl.inversion.invert\n"
            "from warpe_cl.inversion.forward import Forward\n"
            "from warpe_cl.instrument import load_instrument\n"
            "Forward(load_instrument('bela')).waveform(__import__('numpy').ones(3000))\n"
            "assert 'scipy.signal' not in sys.modules, 'scipy.signal imported'\n"
            "assert 'scipy.stats' not in sys.modules, 'scipy.stats imported'\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def _bela_shots(clipped: bool):
    """Forward model, shots of a synthetic return (some clipped when ``clipped``), the model."""
    from warpe_cl.instrument import load_instrument
    from warpe_cl.inversion.forward import Forward
    from warpe_cl.inversion.likelihood import Shots
    f = Forward(load_instrument("bela"))
    photons = np.exp(-0.5 * ((f.t - 20.0) / 3.0) ** 2) * 1e3
    mu, nu = f.waveform(photons, 0.0)
    rng = np.random.default_rng(5)
    t = np.arange(-50.0, 240.0, f.interval)
    scale = (f.ceiling - f.baseline) / mu.max() * (3.0 if clipped else 0.5)
    truth = np.interp(t[None, :] - rng.normal(0.0, 2.0, (12, 1)), f.t, mu)
    samples = f.baseline + scale * truth * rng.gamma(50.0, 1 / 50.0, (12, 1))
    samples = np.minimum(samples + rng.normal(0.0, f.sigma_n, samples.shape), f.ceiling)
    return f, Shots(t, samples, f), photons


def test_a_spectrum_taken_once_gives_the_waveforms_bits():
    from warpe_cl.instrument import load_instrument
    from warpe_cl.inversion.forward import Forward, Spectrum
    for name in ("bela", "atlas"):
        f = Forward(load_instrument(name))
        photons = np.exp(-0.5 * ((f.t - 20.0) / 3.0) ** 2) * 1e3
        kept = Spectrum(photons)
        for v in (0.0, 0.7, -0.3, 4.0, 0.7):
            for got, want in zip(f.waveform(kept, v), f.waveform(photons, v)):
                assert (got is None and want is None) or np.array_equal(got, want), (name, v)


def test_a_shots_terms_do_not_depend_on_the_other_shots():
    # the line search of Shots.fit takes its shorter steps for the shots still pending only
    from warpe_cl.inversion.likelihood import padded
    for clipped in (False, True):
        f, shots, photons = _bela_shots(clipped)
        assert shots.censored.any() == clipped
        mu, nu = f.waveform(photons, 0.0)
        shots.start(mu)
        table = padded([mu, np.gradient(mu, f.t), nu])
        a, d = shots.amplitude * 1.1, shots.arrival + 0.3
        c = f.ceiling - f.baseline
        whole = shots._normal(a, d, table, f.sigma_n ** 2, c)
        for rows in (np.array([3]), np.array([0, 5, 11]), np.arange(1, 12, 2)):
            part = shots._normal(a[rows], d[rows], table, f.sigma_n ** 2, c, rows)
            for x, y in zip(part, whole):
                assert np.array_equal(x, y[rows]), (clipped, rows)


def test_the_database_error_reads_the_fits_own_model_table():
    from dataclasses import replace

    from warpe_cl.inversion.emulator import shared_error
    f, shots, photons = _bela_shots(False)
    mu, nu = f.waveform(photons, 0.3)
    fit = shots.fit(mu, nu)
    assert fit.table is not None
    variance = (0.02 * mu) ** 2
    assert shared_error(shots, fit, mu, nu, variance) == \
        shared_error(shots, replace(fit, table=None), mu, nu, variance)
