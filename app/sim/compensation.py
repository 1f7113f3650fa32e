"""Lag compensation of the emulation loop: command the arm where the satellite will be.

Why (DESIGN.md "Fidelity"): a contact between the mockups is felt by the ODS late twice
over. The mockup reaches an ODS pose ``position_s`` later (VFDM, servo delay and
bandwidth), and the force the contact makes arrives at the ODS ``force_s`` after that
(sensor delay, low-pass, the zero-order hold of one cycle). While two bodies press
together, that lag turns the contact into an energy source: in the sponge collision the
restitution is 1.6 against the physics' 0.30 with nothing to stop it.

The compensation is a model-based predictor (in the spirit of the predictive delay
compensation of hardware-in-the-loop contact test beds, e.g. Krenn & Schäfer, "Limitations
of hardware-in-the-loop simulations of space robotics dynamics using industrial robots",
1999; Ma et al., "Hardware-in-the-loop simulation of contact dynamics", 2004): each cycle
the ODS integrates its own equations (Eqs. 1-7) ``lead_s = position_s + force_s`` ahead
under the input it has just received, and the arm is sent to that predicted pose. The
mockup then *is* where the satellite is ``force_s`` from now, so the force its contact
makes reaches the ODS at the instant the satellite is at that pose: the contact law acts
between the virtual satellites, in time, through the real sensor chain.

What it cannot do: the prediction holds the input constant over ``lead_s``. For a contact
whose force changes a lot within the lead (a stiff contact lasting a few lead times) the
prediction misses by about ``(1/6)(dF/dt / m) lead³``: that, and the sensor's noise, is what
limits the fidelity it reaches (benchmarks/contact_fidelity.py).

The lags come from the loop's own model, as a lab would identify them once: the position
lag by driving copies of the arm's VFDM and servo model along a ramp (for a robot on a
rail, of the 7-joint chain's VFDM, the carriage's servo and the arm's, along the rail,
the motion the carriage carries: its servo's response and delay are then in the lead;
in steady state the mockup trails the chain's set-points by the carriage's lag, its delay
plus ``2ζ/ω`` without velocity feedforward); the force lag in
closed form from the sensor's delay and the discretisation of the filter a contact's
force passes (``[wrench] contact_lowpass_hz`` while the contact gate is open). Since the
miss grows as lead³, a contact path without the 30 Hz low-pass (lead 8.6 ms instead of
12.9 ms in the collision scenario) takes the noise-free rigid–rigid impact from +21 % to
+3 % (the passivity layer off; tuning seed 1000).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.config import EmulatorConfig, RobotConfig
from app.sim.feedforward import send, servo_feedforward
from app.sim.ft_sensor import lowpass_alpha
from app.sim.orbital import OrbitalSimulator
from app.sim.rail import chain_tcp_pose
from app.sim.rail_servo import RailServo
from app.sim.rail_vfdm import RailVfdm
from app.sim.sensor_models import hold_lag_cycles
from app.sim.servo import UR10eServo
from app.sim.ur10e import T_W_B_from_config, tcp_pose_B
from app.sim.vfdm import JointLimits, Vfdm

__all__ = ["LagModel", "LagModelError", "contact_cutoff_hz", "force_lag_s",
           "identify_position_lag_s", "lag_model", "predicted_state"]

RAMP_SPEED_MPS = 0.05
RAMP_S = 0.8
"""A ramp this long (at any loop rate) shows the steady lag; doubled up to MAX_RAMP_S
while the lag still drifts."""
MAX_RAMP_S = 6.4
CONVERGED_S = 1e-4
"""The lag has settled when it moved less than this over the ramp's last quarter."""
MAX_LEAD_S = 0.1


class LagModelError(ValueError):
    """The loop's lag could not be identified, or is beyond what a lead can make up."""


@dataclass(frozen=True)
class LagModel:
    """The loop's lags, in seconds."""

    position_s: float
    """ODS pose → the mockup there (VFDM, servo delay and response), for a steady ramp."""
    force_s: float
    """A force on the mockup → the ODS's input (sensor delay, low-pass, zero-order hold)."""

    @property
    def lead_s(self) -> float:
        return self.position_s + self.force_s


def identify_position_lag_s(config: EmulatorConfig, T_F_C: np.ndarray,
                            q0_rad: np.ndarray, tick=None, robot: RobotConfig | None = None,
                            s0_m: float | None = None) -> float:
    """How far behind a steady ramp target the mockup follows, in seconds.

    ``robot`` with a rail (its carriage at ``s0_m``, default the rail's start): the ramp
    runs along the rail, through copies of the chain's VFDM, the carriage's servo and the
    arm's, as app/sim/rail_rig.py RailRig.command drives them (:func:`_rail_ramp_lags_s`).

    Copies of the arm's VFDM, servo feedforward (if on) and servo model (not the arm
    itself) start at rest at
    ``q0_rad`` and follow a TCP target that moves at RAMP_SPEED_MPS along the base x axis,
    in the loop's order: the target of t_k+1 → VFDM → one servo step → the mockup at t_k+1.
    The ramp lasts RAMP_S, doubled while the lag still moves by more than CONVERGED_S over
    its last quarter. Raises LagModelError if it never settles. The lag may be negative: with
    the servo feedforward the arm follows the VFDM's set-points, and the VFDM's velocity
    feedforward puts them slightly ahead of the target (:func:`lag_model` checks the total).
    """
    dt_s = 1.0 / config.loop.rate_hz
    ramp_s = RAMP_S
    tick = tick or (lambda: None)
    while True:
        if robot is not None and robot.rail is not None:
            lags_s = _rail_ramp_lags_s(config, robot, T_F_C, q0_rad,
                                       robot.rail.start_m if s0_m is None else s0_m,
                                       dt_s, ramp_s, tick)
        else:
            lags_s = _ramp_lags_s(config, T_F_C, q0_rad, dt_s, ramp_s, tick)
        drift_s = abs(lags_s[-1] - lags_s[0])
        if drift_s <= CONVERGED_S:
            break
        if 2.0 * ramp_s > MAX_RAMP_S:
            raise LagModelError(
                f"the position lag did not settle within a {ramp_s:g} s ramp at "
                f"loop.rate_hz = {config.loop.rate_hz:g} Hz (it still moved "
                f"{1e3 * drift_s:.2f} ms over the last quarter): the arm's tracking "
                f"oscillates at this rate, and no lead would steady it; raise loop.rate_hz "
                f"(it settles at 500 Hz and above) or set compensation.enabled = false")
        ramp_s *= 2.0
    return float(lags_s[-1])


def _sample_ramp(dt_s: float, ramp_s: float, tick, advance, lag_s) -> np.ndarray:
    """Drive a chain along a ramp of ``ramp_s``: ``advance(k)`` runs cycle k (target, VFDM,
    servos); ``lag_s(k)`` is the mockup's lag behind the target after it, taken at 3/4 of
    the ramp and at its end; tick() now and then (a supervisor's heartbeat)."""
    cycles = max(4, int(round(ramp_s / dt_s)))
    check = {(3 * cycles) // 4, cycles}
    lags = []
    for k in range(1, cycles + 1):
        advance(k)
        if k % 50 == 0:
            tick()
        if k in check:
            lags.append(lag_s(k))
    return np.array(lags)


def _ramp_lags_s(config: EmulatorConfig, T_F_C: np.ndarray, q0_rad: np.ndarray,
                 dt_s: float, ramp_s: float, tick) -> np.ndarray:
    """The lag (s) of the fixed arm at 3/4 of a ramp of ``ramp_s`` along the base's x and at
    its end (:func:`_sample_ramp`)."""
    vfdm = Vfdm(config.vfdm, T_F_C, q0_rad, JointLimits.of_servo(config.servo, dt_s))
    servo = UR10eServo(config.servo, dt_s, q0_rad)
    feedforward = servo_feedforward(config, q0_rad)
    T0 = vfdm.tcp_pose()
    T = T0.copy()

    def advance(k: int) -> None:
        T[0, 3] = T0[0, 3] + RAMP_SPEED_MPS * k * dt_s
        if config.vfdm.sync_to_measured:  # as ArmRig.command does
            vfdm.q_rad[:] = servo.state.q_rad
        send(servo, feedforward, vfdm.solve(T))

    def lag_s(k: int) -> float:
        mockup = tcp_pose_B(servo.state.q_rad, T_F_C)
        return (T[0, 3] - mockup[0, 3]) / RAMP_SPEED_MPS

    return _sample_ramp(dt_s, ramp_s, tick, advance, lag_s)


def _rail_ramp_lags_s(config: EmulatorConfig, robot: RobotConfig, T_F_C: np.ndarray,
                      q0_rad: np.ndarray, s0_m: float, dt_s: float, ramp_s: float,
                      tick) -> np.ndarray:
    """:func:`_ramp_lags_s` for a robot on a rail: the TCP target moves along the rail's
    axis; the chain's VFDM (its posture: the rail's posture_rad, else q0) sends the
    carriage's set-point to a copy of its servo and the arm's to the arm's (through the
    servo feedforward, if on); the mockup is the chain's TCP at the carriage's and the
    arm's actual positions."""
    rail = robot.rail
    limits = JointLimits.of_servo(config.servo, dt_s)
    q0 = np.concatenate([[s0_m], q0_rad])
    posture = np.asarray(q0_rad if rail.posture_rad is None else rail.posture_rad, float)
    vfdm = RailVfdm(config.vfdm, rail, T_W_B_from_config(robot), T_F_C, q0, posture, limits)
    carriage = RailServo(rail, dt_s, s0_m)
    servo = UR10eServo(config.servo, dt_s, q0_rad)
    feedforward = servo_feedforward(config, q0_rad)
    axis = vfdm.arm.axis
    T0 = vfdm.tcp_pose()
    T = T0.copy()

    def advance(k: int) -> None:
        T[:3, 3] = T0[:3, 3] + RAMP_SPEED_MPS * k * dt_s * axis
        if config.vfdm.sync_to_measured:  # as RailRig.command does
            vfdm.q[0] = carriage.state.s_m
            vfdm.q[1:] = servo.state.q_rad
        q = vfdm.solve(T)
        carriage.step(q[0])
        send(servo, feedforward, q[1:])

    def lag_s(k: int) -> float:
        mockup = chain_tcp_pose(vfdm.arm, np.concatenate([[carriage.state.s_m],
                                                           servo.state.q_rad]))
        return float((T[:3, 3] - mockup[:3, 3]) @ axis) / RAMP_SPEED_MPS

    return _sample_ramp(dt_s, ramp_s, tick, advance, lag_s)


def contact_cutoff_hz(config: EmulatorConfig) -> float:
    """The low-pass's cut-off a contact's force passes: ``contact_lowpass_hz`` while the
    contact gate is open, else ``lowpass_hz``."""
    wrench = config.wrench
    if wrench.contact_gate and wrench.contact_lowpass_hz is not None:
        return wrench.contact_lowpass_hz
    return wrench.lowpass_hz


def _cutoff_setting(config: EmulatorConfig) -> str:
    """The setting :func:`contact_cutoff_hz` reads, by name."""
    wrench = config.wrench
    if wrench.contact_gate and wrench.contact_lowpass_hz is not None:
        return "wrench.contact_lowpass_hz"
    return "wrench.lowpass_hz"


def force_lag_s(config: EmulatorConfig, hold: bool = True) -> float:
    """Sensor delay + the low-pass's ramp lag (1 − α)/α cycles (+ with ``hold``, the half
    cycle by which the ODS's zero-order hold of the force lags the force itself) + the
    sensor's own hold when it samples slower than the loop ((N − 1)/2 cycles on average,
    app/sim/sensor_models.py hold_lag_cycles); α of the filter a contact's force passes
    (:func:`contact_cutoff_hz`)."""
    dt_s = 1.0 / config.loop.rate_hz
    alpha = lowpass_alpha(contact_cutoff_hz(config), config.loop.rate_hz)
    held = hold_lag_cycles(config.sensor.sample_rate_hz, config.loop.rate_hz)
    return (config.sensor.delay_cycles + (1.0 - alpha) / alpha + 0.5 * hold + held) * dt_s


def lag_model(config: EmulatorConfig, T_F_C: np.ndarray, q0_rad: np.ndarray,
              tick=None, robot: RobotConfig | None = None,
              s0_m: float | None = None) -> LagModel:
    """The lags of the arm with mockup offset T_F_C, identified around posture q0_rad (on
    ``robot``'s rail, if it has one, with the carriage at ``s0_m``).
    Raises LagModelError if their sum is not positive (no lag a lead could make up), or
    beyond MAX_LEAD_S (the largest lead the configuration accepts: a prediction that far
    ahead is no longer a small correction)."""
    model = LagModel(identify_position_lag_s(config, T_F_C, q0_rad, tick, robot, s0_m),
                     force_lag_s(config))
    if not model.lead_s > 0.0:
        raise LagModelError(f"the ODS's input does not trail the satellites (lag "
                            f"{1e3 * model.lead_s:.2f} ms): set compensation.lead_s by hand, "
                            f"or compensation.enabled = false")
    if model.lead_s > MAX_LEAD_S:
        raise LagModelError(
            f"the loop's lag is {1e3 * model.lead_s:.0f} ms ({1e3 * model.position_s:.0f} ms "
            f"to the mockup, {1e3 * model.force_s:.0f} ms back from the sensor with "
            f"{_cutoff_setting(config)} = {contact_cutoff_hz(config):g} Hz, "
            f"sensor.delay_cycles = {config.sensor.delay_cycles} at loop.rate_hz = "
            f"{config.loop.rate_hz:g} Hz), beyond the {1e3 * MAX_LEAD_S:.0f} ms a lead can "
            f"make up: a faster filter or servo, a higher rate, or "
            f"compensation.enabled = false")
    return model


def predicted_state(ods: OrbitalSimulator, force_R_N: np.ndarray, torque_B_Nm: np.ndarray,
                    lead_s: float) -> np.ndarray:
    """The ODS state ``lead_s`` ahead under the input held (one RK4 step of Eqs. 1-7)."""
    if lead_s <= 0.0:
        return ods.y
    return ods.advance(force_R_N, torque_B_Nm, lead_s)
