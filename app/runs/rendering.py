"""How well the arms rendered a contact: the mockups against the satellites they carry.

The contact law acts between the actual mockups. It is the satellites' contact only
while the mockups are where the satellites will be one force lag ``τ_f`` later
(app/sim/compensation.py: the force the mockups make reaches the ODS ``τ_f`` after it is
made). So the run itself shows how far its contact is the satellites': over the cycles
the bodies touch, along the contact normal n,

    e(t) = [(p_b − p_a)_mockups(t) − (p_b − p_a)_satellites(t + τ_f)] · n              (R1)

(positions in R; a satellite no arm carries is its own mockup). Its rms is the
*rendering error*; the scale it is read against is the *approach depth*, how far the
satellites moved into each other over the same cycles (the range of their separation
along n). A restitution can come out near the ideal one while the mockups were far off
the satellites' course, the errors of the way in and the way out cancelling: (R1) tells
such a coincidence from a rendered contact.

What limits it on a stiff contact is the arm's acceleration: the shipped rigid vs rigid
collision asks the arms for about the acceleration the VFDM keeps their set-points to
(docs/explanation/contact-fidelity.md, "What limits a stiff contact").
"""

from __future__ import annotations

import numpy as np

__all__ = ["RENDERING_TOLERANCE", "rendering_error", "rendering_warning", "unrendered_share"]

RENDERING_TOLERANCE = 0.1
"""A rendering error beyond this share of the approach depth is said: the contact the
mockups had is no longer the satellites' to within the sensor-free part of the chain."""


def _position(rows: np.ndarray, index: dict, prefix: str) -> np.ndarray:
    """(N, 3) a body's position columns (R)."""
    return rows[:, [index[f"{prefix}_{axis}_m"] for axis in "xyz"]]


def _touching(rows: np.ndarray, coll: dict) -> np.ndarray:
    """Rows of the contact's touching cycles, first to last touch."""
    t = rows[:, 0]
    return np.nonzero((t >= coll["contact_start_s"] - 1e-9)
                      & (t <= coll["contact_end_s"] + 1e-9))[0]


def rendering_error(rows: np.ndarray, index: dict, coll: dict, bodies: dict[int, str],
                    force_lag_s: float) -> dict:
    """Eq. R1 over the first contact of ``coll`` (app/runs/metrics.py collision_metrics):
    {"rendering_error_m": its rms, "rendering_error_max_m": its largest magnitude,
    "approach_depth_m"}. ``bodies``: per satellite (1-based) the telemetry prefix of its
    mockup ("rob2"); ``force_lag_s``: τ_f."""
    a, b = (int(name[3:]) for name in coll["pair"])
    n = np.asarray(coll["normal"], dtype=float)
    t = rows[:, 0]
    mock = (_position(rows, index, bodies.get(b, f"sat{b}"))
            - _position(rows, index, bodies.get(a, f"sat{a}"))) @ n
    sat = (_position(rows, index, f"sat{b}") - _position(rows, index, f"sat{a}")) @ n
    k = _touching(rows, coll)
    sat_later = np.interp(t[k] + force_lag_s, t, sat)
    e = mock[k] - sat_later
    return {"rendering_error_m": float(np.sqrt(np.mean(e * e))),
            "rendering_error_max_m": float(np.abs(e).max()),
            "approach_depth_m": float(sat_later.max() - sat_later.min())}


def unrendered_share(figures: dict) -> float | None:
    """The rendering error's share of the approach depth where it exceeds
    RENDERING_TOLERANCE (the arms did not render the contact); None within it, or without
    the figures (``rendering_error_m``, ``approach_depth_m``: a collision's or a forecast's)."""
    err, depth = figures.get("rendering_error_m"), figures.get("approach_depth_m")
    if err is None or not depth or err <= RENDERING_TOLERANCE * depth:
        return None
    return err / depth


def rendering_warning(coll: dict) -> str | None:
    """The sentence a run says when the arms did not render its contact (None else)."""
    share = unrendered_share(coll)
    if share is None:
        return None
    return (f"the arms did not render this contact: its rendering error (Eq. R1) is "
            f"{100 * share:.0f} % of the approach depth, beyond "
            f"{100 * RENDERING_TOLERANCE:.0f} %; this restitution is the arms' as much as "
            f"the contact law's, and can match the ideal one only by chance")
