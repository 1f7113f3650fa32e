"""How large a velocity change a push may give a satellite before its arm can no longer
follow it within ``[loop] max_tracking_error_m`` (hil, the real F/T chain and servo;
app/backend/service.py ``push_motion_limits``).

    .venv/bin/python -m benchmarks.push_follow            # 3 scenarios x 2 forces x 2 directions
    .venv/bin/python -m benchmarks.push_follow --quick    # collision, the push limit, +y

Each case: a push of a given force along an axis of R from 0.2 s after the start, its
duration found by bisection (12 steps) as the longest the arm follows: the run goes on and
the mockup's largest distance from its ODS position over the push and 0.5 s after stays
within the scenario's max_tracking_error_m. The velocity change it gives is
force_scale |F| T / m (the ODS's own law). Printed: per case the largest Δv followed and
the acceleration force_scale |F| / m ("≥" where the longest push the web app takes was
followed: not a limit, left out of the smallest); then the smallest Δv over all cases and
the limit the web app uses (that times MOTION_MARGIN, rounded down).
"""

from __future__ import annotations

import argparse

import numpy as np

from app.backend.service import (
    MAX_PUSH_DURATION_S,
    MAX_PUSH_DV_MPS,
    MOTION_MARGIN,
    push_limit,
)
from app.config import merge_overrides
from app.scenarios import load_scenario
from app.sim.hand import Push
from app.sim.loop import Emulator
from app.sim.scaling import scaling_of

START_S = 0.2
AFTER_S = 0.5


def peak_error_m(scenario: str, force_R_N: np.ndarray, duration_s: float,
                 seed: int = 0) -> tuple[float, str]:
    """(the largest tracking error of satellite 1's arm over the push and AFTER_S after it,
    the first two words of the run's stop reason, "" if it went on)."""
    config = merge_overrides(load_scenario(scenario), {"loop": {"seed": seed}})
    em = Emulator(config, mode="hil")
    em.prepare()
    rate = config.loop.rate_hz
    for _ in range(int(START_S * rate)):
        em.step()
    em.post(Push(satellite=0, force_R_N=tuple(force_R_N), duration_s=duration_s))
    arm = next(a for a in em.arms if a.satellite == 0)
    peak = 0.0
    for _ in range(int((duration_s + AFTER_S) * rate)):
        em.step()
        if em.status != "running":
            reason = (em.safety_stop or {}).get("reason", em.status)
            return float("inf"), " ".join(reason.split(" ")[:2])
        p_R, _ = em.mockup_pose_R(arm)
        peak = max(peak, float(np.linalg.norm(p_R - em.ods.position_m[0])))
    return peak, ""


def longest_followed_s(scenario: str, force_R_N: np.ndarray, steps: int = 12) -> float:
    """The longest push of force_R_N the arm follows (bisection up to the longest push
    the web app takes, MAX_PUSH_DURATION_S)."""
    bound = load_scenario(scenario).loop.max_tracking_error_m
    lo, hi = 0.0, MAX_PUSH_DURATION_S
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        error, _ = peak_error_m(scenario, force_R_N, mid)
        lo, hi = (mid, hi) if error <= bound else (lo, mid)
    return lo


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    scenarios = ["collision"] if args.quick else ["collision", "free-floating", "docking"]
    directions = [np.array([0.0, 1.0, 0.0])] if args.quick else [
        np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0])]
    fractions = [1.0] if args.quick else [1.0, 0.1]
    print("| scenario | force (N) | direction (R) | acceleration (m/s²) | longest push (s) | "
          "Δv followed (m/s) |")
    print("|---|---|---|---|---|---|")
    smallest = np.inf
    for name in scenarios:
        config = load_scenario(name)
        limit_N, _ = push_limit(config, 0)
        per_N = scaling_of(config).force_scale / config.satellites[0].mass_kg
        for fraction in fractions:
            for d in directions:
                force_N = fraction * limit_N
                T = longest_followed_s(name, force_N * d)
                dv = per_N * force_N * T
                capped = T > MAX_PUSH_DURATION_S - 0.01  # followed to the longest push
                if not capped:
                    smallest = min(smallest, dv)
                print(f"| {name} | {force_N:.2f} | {d.astype(int).tolist()} | "
                      f"{per_N * force_N:.3g} | {'≥ ' if capped else ''}{T:.4f} | "
                      f"{'≥ ' if capped else ''}{dv:.3f} |")
    print(f"\nsmallest Δv followed: {smallest:.3f} m/s; with the margin {MOTION_MARGIN:g}, "
          f"rounded down to 0.01: {np.floor(100 * MOTION_MARGIN * smallest) / 100:.2f} m/s; "
          f"the web app's MAX_PUSH_DV_MPS = {MAX_PUSH_DV_MPS:g} m/s")


if __name__ == "__main__":
    main()
