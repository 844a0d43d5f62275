"""The likelihood of recorded linear-mode shots given a model waveform (docs/inversion.md §4).

Shot s, sample k at time t_k (ns) records

    x_sk = baseline + a_s μ(t_k − δ_s) + ε_sk,   Var ε_sk = σ_n² + a_s ν(t_k − δ_s),

with μ, ν from :class:`warpe_cl.inversion.forward.Forward`, a_s the shot's amplitude and δ_s
its arrival (range offset plus the unknown sampling phase: the return is not locked to the ADC
clock, and real shots do not share one range). Shot noise with APD excess, electronic and
background noise and quantisation make up the variance (Gaussian: tens to thousands of
photoelectrons per sample). A clipped sample (at the saturation level or the top ADC code) is
censored: it says only x ≥ c and counts log P(x ≥ c) = log ½ erfc((c − m)/√(2 Var)).

Per-shot nuisances, marginalised by Laplace's method around their best fit (Gauss–Newton):

- δ_s with a flat prior (the same for every model, so it drops out);
- a_s = A S_s with the speckle factor S_s ~ Gamma(M, 1/M) of docs/instrument.md §3.3, taken as
  N(A, A²/M); integrating a_s against the data's Gaussian approximation N(â_s, 1/P_s) gives the
  factor N(â_s; A, 1/P_s + A²/M), and the overall amplitude A is profiled (its weighted mean)
  unless it is fixed.

So log L = Σ_s [ℓ_s(â_s, δ̂_s) + log 2π − ½ log det H_s + log N(â_s; A, 1/P_s + A²/M)], with
H_s the Gauss–Newton Hessian of −ℓ_s in (a, δ) and P_s = det H_s / H_s[δδ] the precision of
a_s once δ_s is integrated out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import log_ndtr

LOG_2PI = math.log(2.0 * math.pi)


@dataclass
class ShotFit:
    """The per-shot nuisances at one model: amplitude a_s, arrival δ_s (ns), and the parts of
    the log-likelihood."""
    amplitude: np.ndarray
    arrival: np.ndarray
    loglike: float
    overall: float          # A
    chi2: float             # Σ r²/Var over uncensored samples
    samples: int            # uncensored samples
    censored: int


class Shots:
    """Recorded shots and what does not change between models.

    Parameters
    ----------
    time_ns : array (K,)
        Nominal sample times, ns.
    samples : array (S, K)
        Recorded samples, mV.
    forward : Forward
        Noise level, baseline, ceiling and speckle modes.
    """

    def __init__(self, time_ns, samples, forward):
        self.t = np.asarray(time_ns, float)
        self.x = np.asarray(samples, float)
        self.f = forward
        self.censored = self.x >= forward.ceiling - 1e-9
        self.y = self.x - forward.baseline           # baseline-subtracted
        self.arrival = None
        self.amplitude = None

    def start(self, mu: np.ndarray) -> None:
        """First per-shot arrival and amplitude against model ``mu`` (on the fine grid): a scan
        of δ over ±1.5 sampling intervals around the peak sample (the first clipped one), the
        amplitude at each δ by least squares on the unclipped samples, raised if need be to
        the least that brings the model to the ceiling at every clipped one."""
        t_peak = float(self.f.t[np.argmax(mu)])
        k = np.argmax(np.where(self.censored, np.inf, self.y), axis=1)
        centre = self.t[k] - t_peak
        c = self.f.ceiling - self.f.baseline
        offsets = np.linspace(-1.5, 1.5, 61) * self.f.interval
        best = np.full(len(self.y), np.inf)
        arrival = centre.copy()
        amp = np.ones(len(self.y))
        free = np.where(self.censored, 0.0, self.y)
        for off in offsets:
            delta = centre + off
            m = self._interp(mu, delta)
            mu_free = np.where(self.censored, 0.0, m)
            norm = np.einsum("sk,sk->s", mu_free, mu_free)
            a = np.einsum("sk,sk->s", free, mu_free) / np.where(norm > 0, norm, 1.0)
            reach = np.where(self.censored & (m > 0), c / np.where(m > 0, m, 1.0), 0.0).max(1)
            reach = np.where((self.censored & (m <= 0)).any(1), np.inf, reach)
            a = np.maximum(np.maximum(a, reach), 1e-6)
            r = self.y - a[:, None] * m
            r = np.where(self.censored, np.maximum(r, 0.0), r)     # clipped: only below c counts
            chi = np.where(np.isfinite(a), np.einsum("sk,sk->s", r, r), np.inf)
            better = chi < best
            best = np.where(better, chi, best)
            arrival = np.where(better, delta, arrival)
            amp = np.where(better, a, amp)
        self.arrival, self.amplitude = arrival, np.where(np.isfinite(amp), amp, 1.0)

    def _interp(self, values: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """``values`` (fine grid) at t_k − δ_s, shape (S, K); 0 outside the grid."""
        return self._gather([values], delta)[0]

    def _gather(self, arrays: list, delta: np.ndarray) -> list:
        """Each of ``arrays`` (on the uniform fine grid) linearly interpolated at t_k − δ_s,
        shape (S, K), 0 outside the grid: the index arithmetic of np.interp on a uniform grid,
        done once for all of them."""
        grid = self.f.t
        x = (self.t[None, :] - np.asarray(delta)[:, None] - grid[0]) / (grid[1] - grid[0])
        i = np.floor(x).astype(np.intp)
        frac = x - i
        inside = (i >= 0) & (i < grid.size - 1)
        i = np.where(inside, i, 0)
        out = []
        for values in arrays:
            lo, hi = values[i], values[i + 1]
            out.append(np.where(inside, lo + frac * (hi - lo), 0.0))
        return out

    def fit(self, mu: np.ndarray, nu: np.ndarray, overall: float | None = None,
            iterations: int = 4) -> ShotFit:
        """Gauss–Newton on each shot's (a_s, δ_s) from the last fit, then the Laplace
        log-likelihood of the module docstring. ``overall``: A fixed (None: profiled)."""
        if self.arrival is None:
            self.start(mu)
        dmu = np.gradient(mu, self.f.t)
        a, d = self.amplitude.copy(), self.arrival.copy()
        sig2 = self.f.sigma_n ** 2
        c = self.f.ceiling - self.f.baseline
        limit = 0.5 * self.f.interval
        h, g, ell, chi2, n_unc = self._normal(a, d, mu, dmu, nu, sig2, c)
        for _ in range(iterations):
            det = h[0] * h[2] - h[1] ** 2
            ok = det > 0
            da = np.where(ok, (h[2] * g[0] - h[1] * g[1]) / np.where(ok, det, 1.0), 0.0)
            dd = np.where(ok, (h[0] * g[1] - h[1] * g[0]) / np.where(ok, det, 1.0), 0.0)
            da = np.clip(da, -0.5 * a, 0.5 * a + 1e-3)
            dd = np.clip(dd, -limit, limit)
            # a step is kept for a shot only where it raises ℓ_s; else a quarter, a sixteenth
            pending = np.ones(a.size, bool)
            for shrink in (1.0, 0.25, 0.0625):
                trial_a = np.where(pending, np.maximum(a + shrink * da, 1e-9), a)
                trial_d = np.where(pending, d + shrink * dd, d)
                t_h, t_g, t_ell, _, _ = self._normal(trial_a, trial_d, mu, dmu, nu, sig2, c)
                better = pending & (t_ell > ell)
                a, d = np.where(better, trial_a, a), np.where(better, trial_d, d)
                h = tuple(np.where(better, x, y) for x, y in zip(t_h, h))
                g = tuple(np.where(better, x, y) for x, y in zip(t_g, g))
                ell = np.where(better, t_ell, ell)
                pending &= ~better
                if not pending.any():
                    break
        self.amplitude, self.arrival = a, d
        h, _, ell, chi2, n_unc = self._normal(a, d, mu, dmu, nu, sig2, c)
        det = np.maximum(h[0] * h[2] - h[1] ** 2, 1e-300)
        p_a = det / np.maximum(h[2], 1e-300)
        spread = 0.0 if not math.isfinite(self.f.modes) else 1.0 / self.f.modes
        if overall is None:
            big_a = float(np.sum(p_a * a) / np.sum(p_a))
            for _ in range(3):
                w = 1.0 / (1.0 / p_a + big_a ** 2 * spread)
                big_a = float(np.sum(w * a) / np.sum(w))
        else:
            big_a = float(overall)
        var_a = 1.0 / p_a + big_a ** 2 * spread
        amp_term = -0.5 * (LOG_2PI + np.log(var_a) + (a - big_a) ** 2 / var_a)
        total = float(np.sum(ell + LOG_2PI - 0.5 * np.log(det) + amp_term))
        return ShotFit(a, d, total, big_a, float(chi2), int(n_unc), int(self.censored.sum()))

    def _normal(self, a, d, mu, dmu, nu, sig2, c):
        """Per shot: the Gauss–Newton Hessian of −ℓ_s in (a, δ) as (H_aa, H_aδ, H_δδ), the
        gradient of ℓ_s, ℓ_s itself, and (all shots) Σ r²/Var and the number of uncensored
        samples. A censored sample contributes log Φ(z), z = (m − c)/√Var, whose derivative in
        the model m is λ(z)/√Var and whose curvature is λ(z)(z + λ(z))/Var, λ = φ/Φ (the
        Tobit terms), so that the steps follow the same ℓ_s that is reported."""
        m, dm, n = self._gather([mu, dmu, nu], d)
        var = sig2 + a[:, None] * n
        model = a[:, None] * m
        r = self.y - model
        cens = self.censored
        sd = np.sqrt(var)
        z = (model - c) / sd
        log_phi_z = log_ndtr(z)
        mills = np.exp(-0.5 * z * z - 0.5 * LOG_2PI - log_phi_z)
        grad_m = np.where(cens, mills / sd, r / var)               # ∂ℓ/∂m
        weight = np.where(cens, mills * (z + mills) / var, 1.0 / var)
        j_a, j_d = m, -a[:, None] * dm
        h = (np.sum(weight * j_a * j_a, 1), np.sum(weight * j_a * j_d, 1),
             np.sum(weight * j_d * j_d, 1))
        g = (np.sum(grad_m * j_a, 1), np.sum(grad_m * j_d, 1))
        gauss = -0.5 * (r * r / var + np.log(var) + LOG_2PI)
        ell = np.sum(np.where(cens, log_phi_z, gauss), 1)
        unc = ~cens
        chi2 = float(np.sum(np.where(unc, r * r / var, 0.0)))
        return h, g, ell, chi2, int(unc.sum())
