"""What ``warpe-cl invert`` pays before it inverts: the forward model convolves with the real
FFTs of scipy.fft, the same bits as scipy.signal.fftconvolve, without importing scipy.signal
(0.7 to 1.0 s of every ``warpe-cl invert`` on 2 cores for an instrument with a Gaussian
filter, which needs nothing else of it); the p-value is scipy.special's chi2 survival
function, the same bits as scipy.stats.chi2.sf, without importing scipy.stats (0.45 to
0.65 s)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np

from warpe_cl.inversion.forward import fft_convolve


def test_fft_convolve_is_fftconvolves_bits():
    from scipy.signal import fftconvolve
    rng = np.random.default_rng(3)
    sizes = [(1, 7), (7, 1), (1, 1), (2, 2), (3001, 257), (220, 3000)]
    sizes += [tuple(rng.integers(1, 4000, 2)) for _ in range(200)]
    for n, m in sizes:
        a, b = rng.random(n), rng.random(m)
        assert np.array_equal(fft_convolve(a, b), fftconvolve(a, b, mode="full")), (n, m)


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
