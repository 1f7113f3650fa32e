"""How strong the operator's hand is: the free-floating satellite's velocity after a drag
of the gizmo by d, held for a while, then let go (hil, the real F/T chain).

    .venv/bin/python -m benchmarks.hand_drag

Prints one line per drag; README "Web app" quotes them.
"""

from __future__ import annotations

import numpy as np

from app.scenarios import load_scenario
from app.sim.hand import HandAnchor
from app.sim.loop import Emulator


def drag(distance_m: float, hold_s: float) -> np.ndarray:
    """The ODS velocity (m/s, R) 0.5 s after letting go of a drag along +y."""
    em = Emulator(load_scenario("free-floating"))
    em.prepare()
    rate = em.config.loop.rate_hz
    for _ in range(int(0.5 * rate)):
        em.step()
    _, T_W_C, _, _ = em.arms[0].mockup_state_W()
    em.post(HandAnchor(satellite=0, anchor_W_m=tuple(T_W_C[:3, 3] + [0.0, distance_m, 0.0])))
    for _ in range(int(hold_s * rate)):
        em.step()
    em.post(HandAnchor(satellite=0, anchor_W_m=None))
    for _ in range(int(0.5 * rate)):
        em.step()
    return em.ods.velocity_mps[0].copy()


def main() -> None:
    cfg = load_scenario("free-floating")
    print(f"hand: {cfg.hand.stiffness_Npm / 100:g} N per cm, at most {cfg.hand.max_force_N:g} "
          f"N; force scale {cfg.orbit.force_scale:g}, satellite {cfg.satellites[0].mass_kg:g} "
          f"kg; a scripted push (20 N x 0.3 s) gives 3.0 cm/s")
    for distance_m in (0.03, 0.05, 0.10, 0.20):
        for hold_s in (0.5, 1.0):
            v = drag(distance_m, hold_s)
            print(f"drag {100 * distance_m:.0f} cm, held {hold_s:g} s: v_y {100 * v[1]:.2f} cm/s "
                  f"(across {100 * np.hypot(v[0], v[2]):.2f} cm/s)")


if __name__ == "__main__":
    main()
