"""How well the mockups rendered a contact: their overlap against the satellites'.

The contact law acts between the actual mockups. It is the satellites' contact only
while the mockups overlap as the satellites will one force lag ``τ_f`` later
(app/sim/compensation.py: the force the mockups make reaches the ODS ``τ_f`` after it is
made). So the run itself shows how far its contact was the satellites': over the cycles
the bodies touch,

    e(t) = δ_mockups(t) − δ_satellites(t + τ_f)                                          (R1)

with δ the two boxes' penetration depth at their poses (the contact model's geometry,
app/sim/contact.py; 0 when apart; a satellite no arm carries is its own mockup). Its rms
is the *rendering error*; the scale it is read against is the satellites' largest
overlap over the contact, the *contact depth*. A restitution can come out near the ideal
one while the mockups were far off the satellites' course, the errors of the way in and
the way out cancelling: (R1) tells such a coincidence from a rendered contact. It looks
at the mockups' motion whatever moved them off: the arms' acceleration on a stiff
contact (docs/explanation/contact-fidelity.md, "What limits a stiff contact"), a
carriage's overshoot, a late sensor's force in the lead's prediction.
"""

from __future__ import annotations

import numpy as np

from app.config import EmulatorConfig
from app.sim.contact import BoxContactModel
from app.sim.rotations import make_transform, quat_to_matrix

__all__ = ["RENDERING_FIELDS", "RENDERING_TOLERANCE", "contact_geometry", "rendering_error",
           "rendering_warning", "unrendered_share"]

RENDERING_FIELDS = ("rendering_error_m", "rendering_error_max_m", "contact_depth_m")
"""What :func:`rendering_error` adds to a collision's metrics (null in an ideal run)."""

RENDERING_TOLERANCE = 0.05
"""A rendering error beyond this share of the contact depth is said. Over the rigid
contact's speeds (docs/explanation/contact-fidelity.md) the restitution's error is of the
order of the share or larger: beyond a twentieth, the mockups alone can move it by more
than 5 %."""


def contact_geometry(config: EmulatorConfig) -> BoxContactModel:
    """The boxes the contact acts between (as built: the physics' own)."""
    return BoxContactModel.from_satellites(config.satellites, config.materials, built=True)


def _poses(rows: np.ndarray, index: dict, prefix: str, k: np.ndarray) -> np.ndarray:
    """(len(k), 4, 4) a body's poses (R) at rows k."""
    p = rows[np.ix_(k, [index[f"{prefix}_{a}_m"] for a in "xyz"])]
    q = rows[np.ix_(k, [index[f"{prefix}_q{a}"] for a in "wxyz"])]
    return np.array([make_transform(quat_to_matrix(qi / np.linalg.norm(qi)), pi)
                     for pi, qi in zip(p, q, strict=True)])


def _depths(model: BoxContactModel, a: int, b: int, Ta: np.ndarray, Tb: np.ndarray
            ) -> np.ndarray:
    """Penetration depth (m) of boxes a < b (0-based) at each pair of poses; 0 apart."""
    out = np.zeros(len(Ta))
    for i, (pa, pb) in enumerate(zip(Ta, Tb, strict=True)):
        g = model.geometry(a, b, pa, pb)
        out[i] = 0.0 if g is None else g.depth_m
    return out


def rendering_error(rows: np.ndarray, index: dict, coll: dict, bodies: dict[int, str],
                    force_lag_s: float, model: BoxContactModel) -> dict:
    """Eq. R1 over the first contact of ``coll`` (app/runs/metrics.py collision_metrics):
    {"rendering_error_m": its rms, "rendering_error_max_m": its largest magnitude,
    "contact_depth_m": the satellites' largest overlap}. ``bodies``: per satellite
    (1-based) the telemetry prefix of its mockup ("rob2"); ``force_lag_s``: τ_f;
    ``model``: :func:`contact_geometry`."""
    a, b = sorted(int(name[3:]) for name in coll["pair"])
    t = rows[:, 0]
    touching = np.nonzero((t >= coll["contact_start_s"] - 1e-9)
                          & (t <= coll["contact_end_s"] + 1e-9))[0]
    lag_rows = int(np.ceil(force_lag_s / coll["dt_s"])) + 2
    around = np.arange(max(0, touching[0] - 2), min(len(t), touching[-1] + lag_rows + 1))
    sat = _depths(model, a - 1, b - 1, _poses(rows, index, f"sat{a}", around),
                  _poses(rows, index, f"sat{b}", around))
    mock = _depths(model, a - 1, b - 1,
                   _poses(rows, index, bodies.get(a, f"sat{a}"), touching),
                   _poses(rows, index, bodies.get(b, f"sat{b}"), touching))
    e = mock - np.interp(t[touching] + force_lag_s, t[around], sat)
    return {"rendering_error_m": float(np.sqrt(np.mean(e * e))),
            "rendering_error_max_m": float(np.abs(e).max()),
            "contact_depth_m": float(sat.max())}


def unrendered_share(figures: dict) -> float | None:
    """The rendering error's share of the contact depth where it exceeds
    RENDERING_TOLERANCE (the mockups did not render the contact); None within it, or
    without the figures (``rendering_error_m``, ``contact_depth_m``: a collision's or a
    forecast's)."""
    err, depth = figures.get("rendering_error_m"), figures.get("contact_depth_m")
    if err is None or not depth or err <= RENDERING_TOLERANCE * depth:
        return None
    return err / depth


def rendering_warning(coll: dict) -> str | None:
    """The sentence a run says when its mockups did not render its contact (None else)."""
    share = unrendered_share(coll)
    if share is None:
        return None
    what = ("this restitution is the mockups' motion's as much as the contact law's, and "
            "can match the ideal one only by chance" if coll.get("restitution") is not None
            else "what the contact gave the satellites is the mockups' motion's as much as "
            "the contact law's")
    return (f"the mockups did not render this contact: their rendering error (Eq. R1) is "
            f"{100 * share:.1f} % of the satellites' {1e6 * coll['contact_depth_m']:.0f} µm "
            f"contact depth, beyond {100 * RENDERING_TOLERANCE:.0f} %; {what}")
