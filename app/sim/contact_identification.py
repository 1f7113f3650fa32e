"""Online identification of a contact's Hunt–Crossley law, and the force it predicts.

With the data sheet's noise (σ 1.67 N per sample) against a 3 N sponge contact, handing
the ODS the measured force hands it the noise as well, cycle by cycle; the noise then
moves the mockups during the contact, and the contact's no-pull end rectifies that motion
into a bias (the manual's "Contact fidelity and its limits"). A low-pass would cut the noise
and add lag. The lab has
more than the force to go on: the mockups' known boxes at their encoder poses give the
contact's depth d and its rate ḋ every cycle, noise-free to the encoders' resolution. A
Hunt–Crossley contact (Hunt and Crossley 1975; identified on a sponge by Haddadi and
Hashtrudi-Zaad) is

    F_n = max(0, k d + λ d ḋ)          (λ = k c: the law F = k d (1 + c ḋ))      (HC)

linear in θ = (k, λ). So the measured normal force of each cycle in contact is a sample
of θ·φ with φ = (d, d ḋ) plus the sensor's noise, and the least-squares θ̂ of all the
samples so far (recursive, in information form)

    A = Σ φ φᵀ,   b = Σ φ F,   θ̂ = (A + ε I)⁻¹ b                                 (LS)

identifies the law during the contact itself, from nothing but the F/T readings and the
encoders: no stiffness or damping is read from the configuration or the simulated
contact. The force handed to the ODS is the identified law's, at the depth and rate of
the cycle the reading was taken in (the reading's own delay, so the loop's lag, and the
lead compensating it, are unchanged):

    F̂_n = max(0, θ̂·φ)                                                         (model)

With one sample the fit returns that sample (ε is tiny): the first cycles of a contact
pass about the measured force; as samples accrue, the noise is averaged over the whole
contact so far (for a depth growing linearly, the prediction's noise is about
σ √(3 / n) after n samples). Outside the contact (d ≤ 0 at the reading's cycle while the
gate is open) the law gives zero: the noise of the gate's margin and hold is not handed
over. The identified law is kept per pair of bodies over the run, so that a later touch
of the same pair starts from what the earlier ones taught.

The regressors are scaled (d in mm, d ḋ in mm·(m/s)/0.1) so that both columns are of
order one and ε = 1e-9 regularises only a rank-deficient A (the first sample, or a
contact at constant rate, where only the prediction along φ is determined, which is the
one used).

What it assumes: the contact is a Hunt–Crossley law with exponent 1 in d (the
project's contact law; a Hertzian exponent would be another regressor), the depth the
geometry gives is the contact's (a lab's kinematic calibration error of a millimetre is
a sixth of the sponge's 6 mm), and the measured normal force is the contact's alone (the
loop applies it only where the pair fusion's Newton check holds, or for one mockup
against a body no arm carries).
"""

from __future__ import annotations

import numpy as np

from app.sim.small_solve import solve

__all__ = ["HuntCrossleyFit"]

DEPTH_SCALE_M = 1e-3
"""d is regressed in mm."""
RATE_SCALE_MPS = 0.1
"""ḋ is regressed in units of 0.1 m/s."""
RIDGE = 1e-9
"""ε of (LS), in the scaled units."""


class HuntCrossleyFit:
    """The least-squares Hunt–Crossley law (module doc, LS) of one pair's contact.

    A (symmetric) and b are kept as plain floats: a sample's update is a few products
    and sums, the same IEEE operations the arrays' elementwise ``A += φ φᵀ``,
    ``b += φ F`` and ``A + ε I`` make, without an array call each."""

    def __init__(self) -> None:
        self._a = [0.0, 0.0, 0.0]  # A's (0, 0), (0, 1) = (1, 0) and (1, 1)
        self._b = [0.0, 0.0]
        self.samples = 0
        self._theta = np.zeros(2)

    @property
    def A(self) -> np.ndarray:
        """(2, 2) Σ φ φᵀ of the samples so far (a copy)."""
        a00, a01, a11 = self._a
        return np.array([[a00, a01], [a01, a11]])

    @property
    def b(self) -> np.ndarray:
        """(2,) Σ φ F of the samples so far (a copy)."""
        return np.array(self._b)

    @staticmethod
    def regressor(depth_m: float, depth_rate_mps: float) -> np.ndarray:
        """φ (scaled): (d, d ḋ) in mm and mm·(0.1 m/s)."""
        d = depth_m / DEPTH_SCALE_M
        return np.array([d, d * depth_rate_mps / RATE_SCALE_MPS])

    def update(self, depth_m: float, depth_rate_mps: float, force_N: float) -> None:
        """Add one cycle's measured normal force at its depth and rate (d > 0 only)."""
        if depth_m <= 0.0:
            return
        d = depth_m / DEPTH_SCALE_M  # φ = (p0, p1), as regressor() has it
        p0, p1 = d, d * depth_rate_mps / RATE_SCALE_MPS
        a, b = self._a, self._b
        a[0] += p0 * p0
        a[1] += p0 * p1  # = p1 p0: A's (1, 0), the same product
        a[2] += p1 * p1
        b[0] += p0 * force_N
        b[1] += p1 * force_N
        self.samples += 1
        # A + ε I: ε on the diagonal, + 0.0 off it (what the array sum adds there)
        self._theta = solve(np.array([[a[0] + RIDGE, a[1] + 0.0], [a[1] + 0.0, a[2] + RIDGE]]),
                            np.array(b))

    def predict(self, depth_m: float, depth_rate_mps: float) -> float:
        """F̂_n (N, ≥ 0) of the identified law (module doc, model); 0 apart."""
        if depth_m <= 0.0 or self.samples == 0:
            return 0.0
        # ndarray.dot of two vectors: the very dot kernel that `@` calls, less overhead
        return max(0.0, float(self._theta.dot(self.regressor(depth_m, depth_rate_mps))))

    @property
    def stiffness_Npm(self) -> float:
        """k̂ (N/m)."""
        return float(self._theta[0]) / DEPTH_SCALE_M

    @property
    def damping_spm(self) -> float:
        """ĉ = λ̂ / k̂ (s/m) of F = k d (1 + c ḋ); nan while k̂ is 0."""
        k = float(self._theta[0])
        return float(self._theta[1]) / RATE_SCALE_MPS / k if k else float("nan")
