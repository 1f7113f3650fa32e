"""Contact gate: when the lab lets a contact force below the noise deadband through.

The F/T deadband (4 N by default) keeps sensor noise from flying the satellites, but the
paper's sponge collision peaks at about 3 N: through the deadband the ODS would never feel
it, and the arms would press the mockups together until it did (3x the impulse of the
physics). The lab knows more than the sensor: the mockups' shapes and, from the arms'
joint encoders, where they are. The gate opens an arm's chain (no deadband) while its
mockup touches another body, or is within ``margin_m`` of one and closing in; it stays
open ``hold_cycles`` after that, so the contact's force, which reaches the ODS delayed and
filtered, passes whole. The rest of the time the deadband applies as before.

What the gate costs: while it is open the sensor noise reaches the ODS too (its impulse
grows as σ·sqrt(open time · dt)); a tight margin and a short hold keep that window close to
the contact itself.

Two sensors, one contact: while two carried mockups touch only each other (each the
other's partner, no third body within the margin of either, the gate open for both), both
sensors measure the same contact force, equal and opposite (Newton's third law), unless
something else pushes one of them (an operator's hand). The loop cannot see a hand; it
sees the two sensors. It decides from them: their sum F_a + F_b is the sensors' noise
alone while only the contact acts, so the pair is taken as one contact while

    χ² = (F_a + F_b)ᵀ (Σ_a + Σ_b)⁻¹ (F_a + F_b) ≤ CHI2_THRESHOLD                    (Newton)

Σ_i the covariance of sensor i's filtered force noise, estimated from its rest readings
at the start-up calibration (:meth:`app.sim.ft_sensor.WrenchProcessor.filtered_force_cov`).
With ``fuse`` the gate then hands both satellites the one estimate
``F = (F_b − F_a) / 2``: its noise is 1/√2 of either sensor's, and the momentum the
contact exchanges balances exactly. (The relative velocity, hence the restitution, sees
the same noise either way: the two sensors' noises add.) A pair whose sum is beyond what
the noise explains is passed as each sensor measured it: the push reaches the pushed
satellite, as a lab's sensors would report it.
"""

from __future__ import annotations

import math

import numpy as np

from app.sim.small_solve import solve

__all__ = ["CHI2_THRESHOLD", "ContactGate", "contact_pairs", "fuse_pair_forces",
           "hold_cycles_for", "newton_consistent"]

CHI2_THRESHOLD = 21.11
"""The χ² quantile of 3 degrees of freedom at 1 − 1e-4: a pair that only touches fails the
test (Newton) once in 10,000 cycles (then it is passed unfused for that cycle)."""
COV_FLOOR_N2 = 1e-6
"""Added to the covariance's diagonal (N²): a noiseless sensor's is zero, and two
noiseless chains still differ by up to 1e-6 N in contact (the compensation's rounding):
no sensor is trusted beyond 1 mN."""
_FLOOR_N2 = COV_FLOOR_N2 * np.eye(3)
_FLOOR_N2.flags.writeable = False


def hold_cycles_for(sensor_delay_cycles: int, lowpass_alpha: float) -> int:
    """Cycles for a force step to pass the sensor's delay and decay to 5 % in the filter."""
    if lowpass_alpha >= 0.95:  # a step is through the filter within one cycle
        return sensor_delay_cycles + 1
    return sensor_delay_cycles + math.ceil(math.log(0.05) / math.log(1.0 - lowpass_alpha))


class ContactGate:
    """Per body: is the chain's deadband lifted this cycle?"""

    def __init__(self, n_bodies: int, margin_m: float, hold_cycles: int) -> None:
        if not margin_m >= 0.0:
            raise ValueError(f"margin_m must be >= 0, got {margin_m}")
        self.margin_m = float(margin_m)
        self.hold_cycles = int(hold_cycles)
        self._previous = [math.inf] * n_bodies  # lists: read and written one body at a time
        self._hold = [0] * n_bodies
        self.partner = np.full(n_bodies, -1, dtype=np.int64)
        """Per body, the body that last opened its gate (-1: none yet)."""
        self.alone = np.ones(n_bodies, dtype=bool)
        """Per body: no body but its partner is within the margin."""
        self._at_rest = True  # no hold running, no body near: update_apart changes nothing

    def update(self, clearance_m: np.ndarray, nearest: np.ndarray,
               crowd: np.ndarray | None = None) -> np.ndarray:
        """(N,) bool: open for each body, from its clearance to the nearest other body
        (m, ≤ 0 touching; inf far away), that body's index this cycle and how many bodies
        are within the margin (``crowd``; None: at most the nearest). Also updates
        :attr:`partner` and :attr:`alone`."""
        previous, hold, partner, alone = self._previous, self._hold, self.partner, self.alone
        self._at_rest = False
        open_ = np.zeros(len(hold), dtype=bool)
        for i in range(len(hold)):  # a few bodies: plain Python beats array calls
            c = float(clearance_m[i])
            if c <= 0.0 or (c < self.margin_m and c < previous[i]):
                hold[i] = self.hold_cycles + 1
                partner[i] = nearest[i]
            elif hold[i] > 0:
                hold[i] -= 1
            previous[i] = c
            open_[i] = hold[i] > 0
            n = 0 if crowd is None else int(crowd[i])
            alone[i] = n == 0 or (n == 1 and nearest[i] == partner[i])
        return open_

    def update_apart(self) -> np.ndarray:
        """:meth:`update` for a cycle in which no body is within the margin of another
        (every clearance inf, no nearest, no crowd), on plain values: the gates only
        count their holds down; the same outputs and the same state. Once they are out,
        the gate is at rest: the next such cycles leave it as it is."""
        previous, hold = self._previous, self._hold
        open_ = np.zeros(len(hold), dtype=bool)
        if self._at_rest:
            return open_
        for i in range(len(hold)):
            if hold[i] > 0:
                hold[i] -= 1
                open_[i] = hold[i] > 0
            previous[i] = math.inf
        self.alone.fill(True)
        self._at_rest = not any(hold)
        return open_


def contact_pairs(open_: np.ndarray, partner: np.ndarray, alone: np.ndarray,
                  carried: np.ndarray) -> list[tuple[int, int]]:
    """The pairs (a < b) of carried bodies whose gates are open for each other
    (``partner``: the gate's partners) and that are near nothing else (``alone``). A body
    that touches two others measures the sum of two contacts: it is in no pair."""
    pairs = []
    o, p, al, c = open_.tolist(), partner.tolist(), alone.tolist(), carried.tolist()
    for a in range(len(o)):  # a few bodies: plain Python beats array calls
        if o[a] and c[a] and al[a]:
            b = p[a]
            if b > a and o[b] and c[b] and al[b] and p[b] == a:
                pairs.append((a, b))
    return pairs


def newton_consistent(force_a: np.ndarray, force_b: np.ndarray,
                      noise_cov_sum: np.ndarray) -> bool:
    """Whether two measured forces are equal and opposite within the noise (module doc,
    Newton); noise_cov_sum: Σ_a + Σ_b (3, 3), in the forces' axes."""
    s = force_a + force_b
    chi2 = float(s.dot(solve(noise_cov_sum + _FLOOR_N2, s)))  # `@`'s dot kernel, less overhead
    return chi2 <= CHI2_THRESHOLD


def fuse_pair_forces(force_R: np.ndarray, pairs: list[tuple[int, int]]) -> None:
    """Replace, in place, the measured forces of each pair (a, b) by their common
    estimate ±(F_b − F_a)/2 (module doc)."""
    for a, b in pairs:
        f = 0.5 * (force_R[b] - force_R[a])
        force_R[b], force_R[a] = f, -f
