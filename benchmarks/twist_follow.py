"""How fast a twist may spin a satellite before its arm can no longer turn the mockup
with it within ``[loop] max_tracking_error_rad`` (hil, free-floating's ceiling arm, the
real F/T chain and servo; app/backend/service.py ``MAX_PUSH_DW_RADPS``).

    .venv/bin/python -m benchmarks.twist_follow

Each case: a push's torque of 2 N m about body z or body x for T seconds from 0.5 s after
the start (the angular-velocity change is torque_scale x 2 N m x T / I), then 3 s on.
Printed: the change, the largest position and attitude tracking errors, and how the run
ended. The web app's limit is MOTION_MARGIN of the smallest change whose attitude error
rose well above the others' (about a quarter of the bound or more).
"""

from __future__ import annotations

import numpy as np

from app.backend.service import MAX_PUSH_DW_RADPS, MOTION_MARGIN
from app.scenarios import load_scenario
from app.sim.hand import Push
from app.sim.loop import Emulator


def twist(axis_B, duration_s: float) -> tuple[float, np.ndarray, str]:
    """(|omega| after, the largest (position m, attitude rad) tracking error, status)."""
    em = Emulator(load_scenario("free-floating"), mode="hil")
    for _ in range(250):
        em.step()
    em.post(Push(0, (0.0, 0.0, 0.0), duration_s, torque_B_Nm=tuple(2.0 * np.asarray(axis_B))))
    worst = np.zeros(2)
    for _ in range(int((duration_s + 3.0) / em.dt_s)):
        em.step()
        if em.status != "running":
            break
        worst = np.maximum(worst, em._tracking_out.max(axis=0))
    status = em.status if em.safety_stop is None else em.safety_stop["reason"]
    return float(np.linalg.norm(em.ods.omega_rel_radps[0])), worst, status


def main() -> None:
    print("| axis | T | delta omega | position error | attitude error | run |")
    print("|---|---|---|---|---|---|")
    for name, axis in (("body z", (0.0, 0.0, 1.0)), ("body x", (1.0, 0.0, 0.0))):
        for duration_s in (0.5, 1.0, 2.0, 3.0, 5.0):
            w, worst, status = twist(axis, duration_s)
            print(f"| {name} | {duration_s:g} s | {w:.3f} rad/s | {1e3 * worst[0]:.1f} mm | "
                  f"{1e3 * worst[1]:.1f} mrad | {status} |", flush=True)
    print(f"the web app's MAX_PUSH_DW_RADPS = {MAX_PUSH_DW_RADPS:g} rad/s "
          f"(MOTION_MARGIN {MOTION_MARGIN:g})")


if __name__ == "__main__":
    main()
