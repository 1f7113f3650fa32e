"""How strong the operator's hand is: the free-floating satellite's velocity after the
gizmo is pressed in by d and held, then let go (hil, the real F/T chain), and that it
never comes back: the hand presses, never pulls (app/sim/hand.py).

    .venv/bin/python -m benchmarks.hand_drag

Each case grabs the mockup at its centre, presses the hand d along +y of R (in one
gizmo update), holds it for hold_s, lets go, and runs 1 s more. Printed per case: the
satellite's v_y at the let-go and 1 s after (cm/s), the largest fall of v_y from one
cycle to the next (it never turns back: at most the orbit's own drift), the most a
steady press of k d gives in that time (force_scale k d hold / m) and the undamped
closed form of a press released from rest, d sqrt(k force_scale / m). docs/hand.md quotes them.
"""

from __future__ import annotations

import numpy as np

from app.scenarios import load_scenario
from app.sim.hand import HandAnchor
from app.sim.loop import Emulator


def press(depth_m: float, hold_s: float) -> tuple[float, float, float]:
    """(v_y at the let-go, v_y 1 s later, the largest fall of v_y in a cycle), m/s."""
    em = Emulator(load_scenario("free-floating"))
    em.prepare()
    rate = em.config.loop.rate_hz
    for _ in range(int(0.5 * rate)):
        em.step()
    _, T_W_C, _, _ = em.arms[0].mockup_state_W()
    grab = T_W_C[:3, 3]
    em.post(HandAnchor(satellite=0, anchor_W_m=tuple(grab)))  # the grab
    em.step()
    em.post(HandAnchor(satellite=0, anchor_W_m=tuple(grab + em.R_W_R @ [0.0, depth_m, 0.0])))
    vy = []
    for _ in range(int(hold_s * rate)):
        em.step()
        vy.append(em.ods.velocity_mps[0][1])
    at_release = vy[-1]
    em.post(HandAnchor(satellite=0, anchor_W_m=None))
    for _ in range(int(1.0 * rate)):
        em.step()
        vy.append(em.ods.velocity_mps[0][1])
    vy = np.array(vy)
    return at_release, vy[-1], float(max(0.0, -np.diff(vy).min()))


def main() -> None:
    cfg = load_scenario("free-floating")
    k, fs, m = cfg.hand.stiffness_Npm, cfg.orbit.force_scale, cfg.satellites[0].mass_kg
    print(f"hand: {k / 100:g} N per cm pressed in, at most {cfg.hand.max_force_N:g} N; force "
          f"scale {fs:g}, satellite {m:g} kg (a {m / fs:g} kg satellite in translation); "
          f"deadband {cfg.wrench.deadband_force_N:g} N")
    print("| press | held | v_y at let-go | 1 s later | largest fall in a cycle | "
          "steady k d | d sqrt(k fs / m) |")
    print("|---|---|---|---|---|---|---|")
    for depth_m in (0.05, 0.10, 0.20):
        for hold_s in (1.0, 5.0):
            v0, v1, fall = press(depth_m, hold_s)
            steady = fs * min(k * depth_m, cfg.hand.max_force_N) * hold_s / m
            print(f"| {100 * depth_m:.0f} cm | {hold_s:g} s | {100 * v0:.2f} cm/s | "
                  f"{100 * v1:.2f} cm/s | {100 * fall:.1e} cm/s | {100 * steady:.2f} cm/s | "
                  f"{100 * depth_m * np.sqrt(k * fs / m):.2f} cm/s |", flush=True)


if __name__ == "__main__":
    main()
