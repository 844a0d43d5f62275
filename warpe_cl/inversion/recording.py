"""What a photon-counting receiver records of a signal rate: its dead time, then its timing
jitter, on the forward grid (docs/inversion.md §4.2).

The recorded rate at amplitude A is J ⊗ R(A s): s the signal photoelectrons per ns at amplitude
1 (:meth:`.forward.Forward.waveform`), R the channels' dead time averaged over the shots'
speckle (:class:`warpe_cl.instrument.photon_counting.DeadTime`, the chain's own
``expected_recorded_counts``, docs/instrument.md §3.9) and J the Gaussian timing jitter
(:meth:`.forward.Forward.jitter`). Far from the signal R is the dark level d E_d; the rows here
are R less that level, which histogram bins add back as a constant. The amplitude enters R
non-linearly (a brighter shot loses a larger share), so the likelihood takes R and its first two
derivatives in A; without dead time R(A s) = A s + d and the model is the linear one.
"""
from __future__ import annotations

import numpy as np

from ..instrument.photon_counting import DeadTime

#: Newton steps of :meth:`Recording.amplitude_for`.
AMPLITUDE_STEPS = 50


class Recording:
    """The recorded rate and its derivatives for one photon-counting :class:`.forward.Forward`.

    Attributes
    ----------
    background : float
        The recorded dark and background rate far from any signal, pe ns⁻¹.
    exact : bool
        Whether the dead-time model is exact: the two timing channels lose nothing when their
        dead time τ_d is at most twice the analog one τ_a (docs/instrument.md §3.9); otherwise
        the recorded rate is an upper bound.
    """

    def __init__(self, forward):
        p = forward.params
        self.f = forward
        self.dead = DeadTime(forward.grid.edges, forward.dc_rate, p["detector.channels"],
                             p["detector.analog_dead_time"], forward.modes, steady=True)
        self.background = self.dead.dark_level
        self.exact = bool(p["detector.digital_dead_time"] <= 2.0 * p["detector.analog_dead_time"])

    @property
    def correlation_ns(self) -> float:
        """The shortest block over which the database's error is taken as common (ns): the
        analog dead time, over which :meth:`gain` assumes it."""
        return self.dead.tau

    @property
    def linear(self) -> bool:
        """No dead time: the recorded rate is A J ⊗ s."""
        return not self.dead.active

    def level(self, s: np.ndarray, amplitude: float) -> np.ndarray:
        """J ⊗ (R(A s) − d E_d): the recorded signal rate, pe ns⁻¹ on the forward grid."""
        if self.linear:
            return amplitude * self.f.jitter(s)
        return self.f.jitter(self.dead.rate(amplitude * s) - self.background)

    def along(self, s: np.ndarray, amplitude: float, w: np.ndarray) -> np.ndarray:
        """J ⊗ DR[A s]·w: how the recorded rate moves with the signal rate along w (pe ns⁻¹
        per unit of w; w = s gives ∂/∂A)."""
        return self.derivative(s, amplitude)(w)

    def derivative(self, s: np.ndarray, amplitude: float):
        """w -> :meth:`along` (s, amplitude, w), the dead time's window of A s taken once for
        every direction it is applied to."""
        if self.linear:
            return self.f.jitter
        derivative = self.dead.derivative(amplitude * s)
        return lambda w: self.f.jitter(derivative(w))

    def expansion(self, s: np.ndarray, amplitude: float) -> tuple:
        """(:meth:`level`, ∂/∂A, ∂²/∂A²) of the recorded rate at ``amplitude``, pe ns⁻¹ on the
        forward grid: J ⊗ of (R(A s) − d E_d, DR[A s]·s, D²R[A s](s, s)); the last is None
        without dead time."""
        if self.linear:
            one = self.f.jitter(s)
            return amplitude * one, one, None
        rate, along, bend = self.dead.expansion(amplitude * s, s)
        return self.f.jitter(rate - self.background), self.f.jitter(along), self.f.jitter(bend)

    def gain(self, s: np.ndarray, amplitude: float, derivative=None) -> np.ndarray:
        """J ⊗ DR[A s]·1: the recorded rate's response to an error of the signal rate that is
        constant over the dead time, per unit error; 1 without dead time. The database's error
        is taken as common over blocks at least that long (:attr:`correlation_ns`,
        docs/inversion.md §4.3); within a block's first τ_a the window still reaches into
        the block before, whose error is independent: there the gain is an approximation.
        ``derivative``: :meth:`derivative` (s, amplitude), when already taken."""
        if self.linear:
            return np.ones_like(s)
        return (derivative or self.derivative(s, amplitude))(np.ones_like(s))

    def amplitude_for(self, s: np.ndarray, signal: float) -> float:
        """The amplitude A at which the recorded signal photons per shot (the whole grid)
        are ``signal``: the lower root where a paralyzable dead time makes the recorded
        count fall again (Newton's method from the no-loss amplitude, which is below it, or
        from 1 if that is lower, each step at most doubling A); where the count stalls below
        ``signal``, the A of the stall."""
        step = self.f.step
        total = float(s.sum()) * step
        if total <= 0.0:
            return 1.0
        a = signal / total
        if self.linear:
            return a
        a = min(a, 1.0)         # below the first stall of the rising count, as a rule

        def count(x):
            rate, along = self.dead.expansion(x * s, s, order=1)
            return (float(np.sum(rate - self.background)) * step,
                    float(np.sum(along)) * step)
        have, slope = count(a)
        for _ in range(AMPLITUDE_STEPS):
            if slope <= 0.0:
                break
            move = min((signal - have) / slope, a)          # at most doubling A
            if abs(move) <= 1e-9 * a:
                break
            have_next, slope_next = count(a + move)
            if slope_next <= 0.0 or have_next < have:   # past a stall: bisect for it
                lo, hi = a, a + move
                for _ in range(AMPLITUDE_STEPS):
                    mid = 0.5 * (lo + hi)
                    lo, hi = (mid, hi) if count(mid)[1] > 0.0 else (lo, mid)
                return lo
            a, have, slope = a + move, have_next, slope_next
        return a
