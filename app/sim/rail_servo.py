"""The rail's carriage servo (DESIGN.md "Rails"): the joints' servo (app/sim/servo.py) on one
prismatic axis, compiled.

Each control cycle the caller hands over one carriage set-point s_sp [m]. The servo

1. delays it by ``delay_cycles`` (transport delay);
2. checks it as a drive's controller does and raises a *protective stop* at the first
   violation: a set-point outside ``travel_m`` or not a number ("rail travel end"), an
   implied speed ``|sp − sp_prev| / dt`` beyond ``speed_limit_mps`` ("rail speed limit"),
   an implied acceleration ``|(sp − sp_prev) / dt − v_sp_prev| / dt`` beyond
   ``accel_limit_mps2`` ("rail acceleration limit"); sp_prev and v_sp_prev are those of
   the last accepted set-point;
3. tracks the accepted set-point with a second-order response of ``bandwidth_hz`` and
   ``damping_ratio``, ``s̈ = ω² (sp − s) + 2ζω (k v_sp − ṡ)``, saturated at the acceleration
   and speed limits (semi-implicit Euler, one step per cycle). k = 1 with
   ``velocity_feedforward`` (the set-points' own speed fed forward, as a linear axis's
   drive is tuned to follow a path: on a ramp the carriage then trails by its delay only,
   where without it a critically damped loop trails by 2ζ/ω more, 32 ms at 10 Hz).

When stopped, the carriage ignores set-points and brakes to rest at the acceleration limit,
then stays halted until :meth:`RailServo.reset`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from app.config import RailConfig

__all__ = ["RailServo", "RailState", "rail_reason_of", "rail_servo_step"]

_REASONS = ("", "rail travel end", "rail speed limit", "rail acceleration limit")


def rail_reason_of(code: int) -> str:
    """The protective-stop reason of a :func:`rail_servo_step` code (0: none)."""
    return _REASONS[code]


@dataclass
class RailState:
    """The carriage's actual state and its stop status."""

    s_m: float
    v_mps: float = 0.0
    a_mps2: float = 0.0
    stopped: bool = False
    reason: str = ""


@njit(cache=True, fastmath=False)
def rail_servo_step(sp_in, ring, slot, prev, x, out, stopped, dt, w2, two_zw, lo, hi,
                    vmax, amax, kv):
    """One cycle; fills out = [s, v, a] from x = [s, v] and returns a new stop's code.

    ring (d,) holds the delayed set-points, ``slot`` the oldest (-1: no delay); prev =
    [sp_prev, v_sp_prev], the last accepted set-point and its implied speed (updated)."""
    sp = sp_in
    if slot >= 0:
        sp, ring[slot] = ring[slot], sp_in
    code = 0
    if not stopped:
        v_sp = (sp - prev[0]) / dt
        tol = 1.0 + 1e-9
        if not (lo <= sp <= hi):  # also catches NaN
            code = 1
        elif abs(v_sp) > vmax * tol:
            code = 2
        elif abs(v_sp - prev[1]) / dt > amax * tol:
            code = 3
        else:
            prev[0], prev[1] = sp, v_sp
    s, v = x[0], x[1]
    if stopped or code != 0:
        acc = -math.copysign(min(amax, abs(v) / dt), v) if v != 0.0 else 0.0
    else:
        acc = w2 * (sp - s) + two_zw * (kv * prev[1] - v)
    acc = min(max(acc, -amax), amax)
    v_new = min(max(v + dt * acc, -vmax), vmax)
    out[0] = s + dt * v_new
    out[1] = v_new
    out[2] = (v_new - v) / dt
    return code


class RailServo:
    """The carriage's position servo: delay, second-order tracking, limits, protective stop."""

    def __init__(self, cfg: RailConfig, dt_s: float, s0_m: float | None = None) -> None:
        self.cfg = cfg
        self.dt_s = float(dt_s)
        w = 2.0 * math.pi * cfg.bandwidth_hz
        self._w2, self._2zw = w * w, 2.0 * cfg.damping_ratio * w
        self.reset(cfg.start_m if s0_m is None else s0_m)

    def reset(self, s_m: float | None = None) -> None:
        """Clear a protective stop; the carriage rests at ``s_m`` (default: where it is)."""
        s = self.state.s_m if s_m is None else float(s_m)
        self.state = RailState(s)
        self._ring = np.full(self.cfg.delay_cycles, s)
        self._slot = 0
        self._prev = np.array([s, 0.0])

    @property
    def stopped(self) -> bool:
        return self.state.stopped

    def step(self, sp_m: float) -> RailState:
        """Advance one cycle with a new set-point; returns the (live) state."""
        st, cfg = self.state, self.cfg
        slot = self._slot if len(self._ring) else -1
        out = np.empty(3)
        code = rail_servo_step(float(sp_m), self._ring, slot, self._prev,
                               np.array([st.s_m, st.v_mps]), out, st.stopped, self.dt_s,
                               self._w2, self._2zw, cfg.travel_m[0], cfg.travel_m[1],
                               cfg.speed_limit_mps, cfg.accel_limit_mps2,
                               1.0 if cfg.velocity_feedforward else 0.0)
        if slot >= 0:
            self._slot = (slot + 1) % len(self._ring)
        st.s_m, st.v_mps, st.a_mps2 = float(out[0]), float(out[1]), float(out[2])
        if code:
            st.stopped, st.reason = True, rail_reason_of(code)
        return st
