"""How close a push at the push limit, with the operator's hand at its cap, comes to the
F/T sensor's range (hil, the real F/T chain; app/backend/service.py ``push_limit``).

    .venv/bin/python -m benchmarks.push_limit            # 3 scenarios x 6 directions x 3 seeds
    .venv/bin/python -m benchmarks.push_limit --quick    # free-floating, down, one seed

Each case: a push at the limit for 0.5 s along one axis of R, and the hand (gizmo) pulling
the same way at its cap (its anchor 1 m off), from 0.1 s after the start; the peak raw F/T
force component of the arm that carries the satellite over the push and 0.2 s after, and
whether the run went on (else the first words of its stop's reason: "F/T force" is the
sensor-range stop the limit prevents; "tracking error" a satellite pushed faster than its
arm can follow, which the limit does not bound). docs/reliability.md quotes the figures.
"""

from __future__ import annotations

import argparse

import numpy as np

from app.backend.service import push_limit
from app.config import merge_overrides
from app.scenarios import load_scenario
from app.sim.hand import HandAnchor, Push
from app.sim.loop import Emulator

DIRECTIONS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                      dtype=float)


def peak_raw_N(scenario: str, direction_R: np.ndarray, seed: int,
               push_s: float = 0.5) -> tuple[float, float, str]:
    """(the push limit, the peak raw force component of arm 1, why the run stopped: ""
    if it went on, else its safety stop's reason up to the first digit)."""
    config = merge_overrides(load_scenario(scenario), {"loop": {"seed": seed}})
    limit_N, _ = push_limit(config, 0)
    em = Emulator(config, mode="hil")
    em.prepare()
    rate = config.loop.rate_hz
    for _ in range(int(0.1 * rate)):
        em.step()
    p_W = em.satellite_pose_W(0)[:3, 3]
    em.post(HandAnchor(satellite=0, anchor_W_m=tuple(p_W)))  # the hand grabs, then
    em.step()  # presses 1 m in along the push: at its cap
    em.post(Push(satellite=0, force_R_N=tuple(limit_N * direction_R), duration_s=push_s))
    em.post(HandAnchor(satellite=0, anchor_W_m=tuple(p_W + em.T_W_R[:3, :3] @ direction_R)))
    arm = next(a for a in em.arms if a.satellite == 0)
    peak = 0.0
    for _ in range(int((push_s + 0.2) * rate)):
        em.step()
        peak = max(peak, float(np.max(np.abs(arm.last_raw_S[:3]))))
        if em.status != "running":
            break
    reason = (em.safety_stop or {}).get("reason", em.status) if em.status != "running" else ""
    return limit_N, peak, reason.split(" ")[0] + " " + reason.split(" ")[1] if reason else ""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    scenarios = ["free-floating"] if args.quick else ["free-floating", "collision", "docking"]
    directions = DIRECTIONS[-1:] if args.quick else DIRECTIONS
    seeds = [0] if args.quick else [0, 1, 2]
    print("| scenario | push limit (N) | sensor range (N) | worst peak raw (N) | "
          "worst direction (R) | runs stopped (why) |")
    print("|---|---|---|---|---|---|")
    for name in scenarios:
        results = [(peak_raw_N(name, d, seed), d) for d in directions for seed in seeds]
        (limit_N, worst, _), d = max(results, key=lambda r: r[0][1])
        why = sorted({reason for (_, _, reason), _ in results if reason})
        stopped = sum(bool(reason) for (_, _, reason), _ in results)
        print(f"| {name} | {limit_N:.2f} | {load_scenario(name).sensor.range_force_N:g} | "
              f"{worst:.1f} | {d.astype(int).tolist()} | {stopped} of {len(results)}"
              f"{' (' + ', '.join(why) + ')' if why else ''} |")


if __name__ == "__main__":
    main()
