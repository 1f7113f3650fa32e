"""One arm rig on a rail: the UR10e's rig (app/sim/rig.py) whose base rides a carriage.

What changes against the fixed rig:

* the actual mockup pose and twist come from the arm's joints *and* the carriage: the base
  is at ``T_W_B(s) = Trans(s · axis_W) · T_W_B0`` and the mockup moves with the carriage's
  speed on top of the arm's twist;
* targets are taken in B0 (the base with the carriage at 0), where the VFDM drives the
  7-joint chain (app/sim/rail_vfdm.py); its set-points go to the carriage's servo
  (app/sim/rail_servo.py) and to the arm's;
* a protective stop of either servo stops both (the cell halts as one): the arm brakes on
  a rail's stop, the carriage on the arm's, and the reason is the one that stopped first;
* the arm's safety box is checked with the base where the carriage's last accepted
  set-point puts it.

Start-up keeps the fixed rig's steps with the carriage at its start position: the start
posture is searched with the base there, the arm moves to it, the sensor calibrates at
rest; the posture term then takes the carriage where the arm is comfortable once the run
starts (within the carriage's limits, the TCP held).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from app.config import EmulatorConfig, RobotConfig
from app.sim.feedforward import send
from app.sim.rail_servo import RailServo
from app.sim.rail_vfdm import RailVfdm
from app.sim.rig import ArmRig, build_rig
from app.sim.rotations import invert_transform
from app.sim.ur10e import T_W_B_from_config, mockup_state

__all__ = ["RailRig", "build_cell", "on_rail"]


@dataclass
class RailRig(ArmRig):
    """An :class:`ArmRig` whose base rides the carriage of a rail."""

    rail_vfdm: RailVfdm | None = None
    rail_servo: RailServo | None = None
    axis_W: np.ndarray | None = None
    """(3,) the rail's unit axis in W."""
    p_W_B0: np.ndarray | None = None
    """(3,) the base's position in W with the carriage at 0."""
    rail_setpoint_m: float = 0.0
    """The carriage set-point of the last cycle."""

    def base_at(self, s_m: float, out: np.ndarray) -> None:
        """out[:3, 3] := the base position with the carriage at s_m (rotation untouched)."""
        out[:3, 3] = self.p_W_B0 + s_m * self.axis_W

    def mockup_state_W(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(T_W_F, T_W_C, v_W, ω_W) with the base where the carriage is and the carriage's
        speed added to the mockup's; cached until either servo steps."""
        st, rs = self.servo.state, self.rail_servo.state
        key = self._state_key
        if (key is None or key[0] is not st.q_rad or key[1] is not st.qd_radps
                or key[2] != rs.s_m or key[3] != rs.v_mps):
            self.base_at(rs.s_m, self.chain.T_W_B)
            out = (np.empty((4, 4)), np.empty((4, 4)), np.empty(3), np.empty(3))
            mockup_state(st.q_rad, st.qd_radps, *self.chain, *out)
            out[2][:] += rs.v_mps * self.axis_W
            self._state, self._state_key = out, (st.q_rad, st.qd_radps, rs.s_m, rs.v_mps)
        return self._state

    def command(self, T_B0_C_target: np.ndarray) -> None:
        """The chain's set-points towards the target (in B0): the carriage's to its servo,
        the arm's (through the servo feedforward, if on) to the arm's; a stop of either
        halts both."""
        vf, rs, arm = self.rail_vfdm, self.rail_servo, self.servo
        if self.vfdm.cfg.sync_to_measured:
            vf.q[0] = rs.state.s_m
            vf.q[1:] = arm.state.q_rad
        q = vf.solve(T_B0_C_target)
        self.rail_setpoint_m = float(q[0])
        rs.step(q[0])
        if arm.safety is not None:
            self.base_at(rs._prev[0], arm.safety.chain.T_W_B)
        send(arm, self.feedforward, q[1:])
        if rs.stopped and not arm.stopped:
            arm.state.stopped, arm.state.reason = True, rs.state.reason
        elif arm.stopped and not rs.stopped:
            rs.state.stopped, rs.state.reason = True, arm.state.reason

    def _fused_command(self) -> None:
        """None: the chain's command (above) takes its stages (the safety box moves with
        the carriage)."""
        return None

    def solve_start_posture(self, T_B0_C_target: np.ndarray, max_steps: int,
                            tick=None) -> tuple[np.ndarray | None, float]:
        """The fixed rig's search with the base where the carriage stands."""
        T = np.array(T_B0_C_target, dtype=float)
        T[:3, 3] -= self.rail_servo.state.s_m * self.rail_vfdm.arm.axis
        return super().solve_start_posture(T, max_steps, tick)

    def calibrate(self, readings_S: np.ndarray) -> None:
        """The fixed rig's calibration; the chain's VFDM starts where the arm and the
        carriage are, and without a configured posture_rad the arm's start posture
        becomes its posture (the one the run's start pose asked for)."""
        super().calibrate(readings_S)
        if self.rail_servo.cfg.posture_rad is None:
            self.rail_vfdm.posture[:] = self.servo.state.q_rad
        self.rail_vfdm.reset(np.concatenate([[self.rail_servo.state.s_m],
                                             self.servo.state.q_rad]))
        self.rail_setpoint_m = self.rail_servo.state.s_m

    def rail_row(self) -> tuple[float, float, float]:
        """The telemetry's (carriage position, speed, set-point)."""
        st = self.rail_servo.state
        return st.s_m, st.v_mps, self.rail_setpoint_m


def on_rail(rig: ArmRig, robot: RobotConfig, config: EmulatorConfig,
            T_W_R: np.ndarray) -> RailRig:
    """The fixed rig ``rig`` of ``robot`` put on its rail (``robot.rail``), the carriage at
    its start position."""
    rail = robot.rail
    dt_s = 1.0 / config.loop.rate_hz
    T_W_B0 = T_W_B_from_config(robot)
    posture = np.array(robot.q_home_rad if rail.posture_rad is None else rail.posture_rad)
    # (without posture_rad, calibrate() puts the start posture there)
    q0 = np.concatenate([[rail.start_m], rig.vfdm.q_rad])
    rail_vfdm = RailVfdm(config.vfdm, rail, T_W_B0, rig.T_F_C, q0, posture,
                         rig.vfdm.limits)
    out = RailRig(**{f.name: getattr(rig, f.name) for f in fields(ArmRig)},
                  rail_vfdm=rail_vfdm, rail_servo=RailServo(rail, dt_s, rail.start_m),
                  axis_W=np.array(rail.axis_W), p_W_B0=T_W_B0[:3, 3].copy(),
                  rail_setpoint_m=rail.start_m)
    out.T_B_R = invert_transform(T_W_B0) @ T_W_R  # targets in B0
    out.base_at(rail.start_m, out.chain.T_W_B)
    if out.servo.safety is not None:
        out.base_at(rail.start_m, out.servo.safety.chain.T_W_B)
    out._state_key = None
    return out


def build_cell(index: int, robot: RobotConfig, config: EmulatorConfig, T_W_R: np.ndarray,
               rng: np.random.Generator) -> ArmRig:
    """The rig of ``robot`` (config.robots[index]) at its home posture: on its rail when
    it has one (:func:`on_rail`), else the fixed arm (app/sim/rig.py build_rig)."""
    rig = build_rig(index, robot, config, T_W_R, rng)
    return rig if robot.rail is None else on_rail(rig, robot, config, T_W_R)
