"""The emulation loop (DESIGN.md "The loop"; paper Fig. 3), one control cycle per `step`.

HIL mode, per cycle::

    joint states q ─► FK: actual mockup poses ─► physical interaction on the ACTUAL mockups
    (contact between mockups, operator's hand) ─► each arm's F/T sensor and processing
    ─► ODS coupling ─► ODS step (all satellites) ─► TCP targets ─► VFDM ─► servos

Ideal mode has no arms: contact is computed directly between the ODS poses, and the ODS
receives the external wrenches exactly (no sensor, no delay, no servo). It is the
reference the HIL run is measured against.

The parts live in their own modules: :mod:`app.sim.rig` (one arm: FK, F/T chain, VFDM,
servo), :mod:`app.sim.interaction` (contact + hand on the bodies), :mod:`app.sim.coupling`
(measured wrench → ODS input), :mod:`app.sim.orbital` (the ODS), :mod:`app.sim.gnc` (a
satellite's own thrusters and wheels, whose wrench enters the ODS directly, not through
the sensor) and :mod:`app.sim.telemetry` (the recorder). The loop wires them, owns their
state and is single-threaded: anything from outside (a REST push, a gizmo drag) arrives as a command
through :meth:`Emulator.post` and is consumed at the start of the next cycle.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import replace

import numpy as np
from pydantic import BaseModel

from app.config import EmulatorConfig
from app.sim import arm_sense
from app.sim.capture import Compound, compound_wrench, join, relative_state, spread
from app.sim.compensation import contact_cutoff_hz, force_lag_s, lag_model, predicted_state
from app.sim.contact import BoxContactModel
from app.sim.contact_estimator import contact_wrench_W
from app.sim.contact_gate import (
    ContactGate,
    contact_pairs,
    fuse_pair_forces,
    hold_cycles_for,
    newton_consistent,
)
from app.sim.contact_identification import HuntCrossleyFit
from app.sim.coupling import OdsCoupling
from app.sim.cycle_tail import RANGE_STOP, sensed_tail_one_arm, tail_one_arm, tail_two_arms
from app.sim.frames import ods_states_W, satellite_pose, tracking_errors
from app.sim.ft_sensor import lowpass_alpha
from app.sim.gnc import GncParams, GncState, gnc_step, navigation
from app.sim.hand import Command, OperatorHand
from app.sim.interaction import (
    Bodies,
    PhysicalInteraction,
    actual_bodies,
    body_torque_B,
    ods_bodies,
)
from app.sim.orbital import OdsParams, OrbitalSimulator, _kernel_args, rk4_step
from app.sim.rail_rig import build_cell
from app.sim.reference import substepped_advance
from app.sim.rig import ArmRig
from app.sim.rotations import (
    invert_transform,
    make_transform,
    matrix_to_quat,
    minus3_floats,
    point_velocity_floats,
    quat_to_matrix,
)
from app.sim.run_up import relative_rates, run_up_state, runs_up
from app.sim.scaling import scaling_of
from app.sim.sensor_models import sample_every_cycles
from app.sim.servo import SafetyBox
from app.sim.telemetry import Recorder
from app.sim.ur10e import TcpChain
from app.sim.vfdm import JointLimits, VirtualArm

__all__ = ["Emulator", "StartPoseError", "tracking_stop_reason"]


SHARED_TYPES = (BaseModel, OdsParams, TcpChain, VirtualArm, JointLimits, SafetyBox)
"""What a copy of the loop (:meth:`Emulator.copy_state`) shares with the loop it copies,
not copied: the configuration (frozen pydantic models) and the models built from it once,
never written (the ODS's parameters, the arms' kinematic chains, virtual arms, joint
limits and safety boxes)."""


def shared_constants(root) -> dict[int, object]:
    """{id: object} of every SHARED_TYPES instance reachable from ``root`` through
    attributes, lists, tuples and dicts: a :func:`copy.deepcopy` memo that shares them."""
    found: dict[int, object] = {}
    seen: set[int] = set()
    todo = [root]
    while todo:
        x = todo.pop()
        if id(x) in seen or isinstance(x, (np.ndarray, str, bytes, int, float, bool)):
            continue
        seen.add(id(x))
        if isinstance(x, SHARED_TYPES):
            found[id(x)] = x
        elif isinstance(x, dict):
            todo.extend(x.values())
        elif isinstance(x, (list, tuple, set, frozenset)):
            todo.extend(x)
        elif hasattr(x, "__dict__") and not isinstance(x, type):
            todo.extend(vars(x).values())
    return found


def _read_only(a: np.ndarray) -> np.ndarray:
    """a, no longer writeable (an answer shared by every cycle)."""
    a.flags.writeable = False
    return a


def _tail_head(ods: OrbitalSimulator, rec: Recorder, force_R: np.ndarray,
               torque_B: np.ndarray, dt_s: float, leads: np.ndarray, ods_out: np.ndarray,
               true_force_R: np.ndarray) -> tuple:
    """The fused tail's arguments up to the arms' (app/sim/cycle_tail.py): ods's step and
    predictions into ods_out under force_R, torque_B (the cycle's own (N, 3) float64
    arrays, passed as they are), the row into rec."""
    return (*_kernel_args(ods.params), ods.y, force_R, torque_B, dt_s, leads, ods_out,
            ods.t_s, rec.orbit_rate_radps, true_force_R, rec._no_gnc, rec._no_rails,
            rec.n_arms, rec.buffer._data, rec.buffer._counters, rec.T_R_W)


def _call_tail(head: tuple, rows: list, targets: list, commands: list) -> tuple:
    """The fused tail's compiled call for one or two arms, in its argument order
    (``head``: :func:`_tail_head`'s; ``rows``: each arm's (T_W_C, v_W, raw, processed);
    ``targets``: its row of the ODS output; ``commands``: :meth:`ArmRig.fused_command_args`).
    (the row's index, then each arm's VFDM scale and servo stop code)."""
    if len(commands) == 1:
        return tail_one_arm(*head, *rows[0], targets[0], *commands[0])
    return tail_two_arms(*head, *rows[0], *rows[1], *targets, *commands[0], *commands[1])


def _call_rest(rig: ArmRig, external_W: np.ndarray, bodies: Bodies, first_cycle: bool,
               R_W_R: np.ndarray, sensed: np.ndarray, range_N: float, head: tuple,
               target: int, command: tuple) -> tuple:
    """:func:`sensed_tail_one_arm` in its argument order: rig's chain on its satellite's
    rows of the cycle's external wrench and bodies (its readings into ``sensed``; a stop at
    ``range_N`` > 0), then the fused tail (``head``: :func:`_tail_head`'s, with the ODS
    input the chain writes its rows into)."""
    T_W_F, T_W_C, v_W, _ = rig.mockup_state_W()
    return sensed_tail_one_arm(rig.satellite, external_W, bodies.T_W_C, bodies.v_W, T_W_F,
                               rig.v_W_prev, first_cycle, R_W_R, sensed, range_N,
                               *arm_sense.chain_args(rig, False), *head, T_W_C, v_W, target,
                               *command)


class StartPoseError(ValueError):
    """A satellite's start pose is out of its arm's reach (a configuration mistake)."""


def _carriage_at(arm: ArmRig) -> float | None:
    """Where a robot's carriage stands (None: a fixed robot)."""
    servo = getattr(arm, "rail_servo", None)
    return None if servo is None else servo.state.s_m


def _beside(value: float, limit: float) -> str:
    """value with one decimal, or up to three where fewer would read as its limit."""
    for digits in (1, 2, 3):
        if round(value, digits) != round(limit, digits):
            break
    return f"{value:.{digits}f}"


def tracking_stop_reason(d_m: float, d_rad: float, max_m: float, max_rad: float) -> str:
    """Why a tracking-error stop stopped: the limit (position or attitude, or both) that the
    error exceeds, with its value and limit, and the other's value within its own, e.g.
    "tracking error: position 61.2 mm exceeds its limit 50 mm (attitude 79.1 mrad within
    250 mrad)"."""
    pos = f"position {_beside(1e3 * d_m, 1e3 * max_m)} mm"
    att = f"attitude {_beside(1e3 * d_rad, 1e3 * max_rad)} mrad"
    lim_m, lim_rad = f"{1e3 * max_m:.4g} mm", f"{1e3 * max_rad:.4g} mrad"
    if d_m > max_m and d_rad > max_rad:
        return (f"tracking error: {pos} exceeds its limit {lim_m} and {att} exceeds its "
                f"limit {lim_rad}")
    if d_rad > max_rad:
        return f"tracking error: {att} exceeds its limit {lim_rad} ({pos} within {lim_m})"
    return f"tracking error: {pos} exceeds its limit {lim_m} ({att} within {lim_rad})"


class Emulator:
    """Dual-arm (any number of arms) on-orbit emulation loop: the paper's Fig. 3, one
    :meth:`step` per loop cycle (``1 / config.loop.rate_hz`` seconds).

    ``mode`` "hil" builds one arm rig per ``[[robots]]`` entry (VFDM, servo, F/T sensor
    and its processing) and closes the loop through them; "ideal" integrates the
    contact directly between the ODS poses, with no arm, sensor or delay (the
    reference). :meth:`prepare` calibrates the sensors and brings the arms to the start
    pose; :meth:`run` then steps for a given time; :meth:`post` queues a command (a
    push, a stop) taken at the next cycle. Telemetry rows are in ``recorder``.

    ``status``: "idle" (before :meth:`prepare`), "running", "finished", "safety_stop"
    (see ``safety_stop``) or "stopped" (set by the one who stopped it).

    Example:
        ```python
        em = Emulator(load_scenario("collision"), mode="ideal")
        em.prepare()
        em.run(2.0)
        ```
    """

    def __init__(self, config: EmulatorConfig, mode: str | None = None) -> None:
        self.config = config
        self.mode = mode or config.loop.mode
        if self.mode not in ("hil", "ideal"):
            raise ValueError(f"mode must be 'hil' or 'ideal', got {self.mode!r}")
        if self.mode == "hil" and not config.robots:
            raise ValueError("hil mode needs at least one [[robots]] entry")
        self.fuse_tail = True
        """Whether a cycle's tail (the ODS step, the telemetry row, each arm's command) runs
        as one compiled call where the configuration allows (app/sim/cycle_tail.py: the
        same numbers); False: always the stages one by one, as :meth:`step` reads."""
        self.dt_s = 1.0 / config.loop.rate_hz
        self.T_W_R = make_transform(
            quat_to_matrix(config.lab.r_attitude_wxyz), config.lab.r_origin_m
        )
        self.T_R_W = invert_transform(self.T_W_R)
        self.R_W_R = self.T_W_R[:3, :3]
        self._R_W_R_c = np.ascontiguousarray(self.R_W_R)
        """R_W_R C-ordered: ``V.dot(_R_W_R_c)`` is ``V @ R_W_R`` to the last bit (the same
        BLAS product; tests/test_loop.py) for a third less overhead."""
        self.ods = OrbitalSimulator.from_config(config)
        self.n_sat = len(config.satellites)
        self.hand = OperatorHand(config, self.R_W_R)
        self.interaction = PhysicalInteraction(
            BoxContactModel.from_satellites(config.satellites, config.materials, built=True),
            self.hand)
        self._drawn_boxes = None  # the lab's geometry where the mockups differ from it
        if any(s.size_error_m != 0.0 for s in config.satellites):
            self._drawn_boxes = BoxContactModel.from_satellites(config.satellites,
                                                                config.materials)
        self.arms: list[ArmRig] = []
        if self.mode == "hil":
            seeds = np.random.SeedSequence(config.loop.seed).spawn(len(config.robots))
            self.arms = [build_cell(i, robot, config, self.T_W_R, np.random.default_rng(seeds[i]))
                         for i, robot in enumerate(config.robots)]
        self._uncarried = sorted(set(range(self.n_sat)) - {arm.satellite for arm in self.arms})
        self._carried = np.array([arm.satellite for arm in self.arms], dtype=np.int64)
        self._is_carried = np.zeros(self.n_sat, dtype=bool)
        self._is_carried[self._carried] = True
        self._arm_of = {arm.satellite: k for k, arm in enumerate(self.arms)}
        self.consistent_pairs: list[tuple[int, int]] = []
        """The pairs of carried mockups this cycle's open gates took as one contact."""
        self._tracking_out = np.zeros((len(self.arms), 2))
        self.coupling = OdsCoupling(
            config.passivity, self.dt_s, [arm.satellite for arm in self.arms],
            list(self.ods.params.mass_kg), self.ods.params.force_scale,
            int(round(force_lag_s(config, hold=False) / self.dt_s)))
        self.gate = None
        self._gate_closed = (_read_only(np.zeros(self.n_sat, dtype=bool)),
                             _read_only(np.full(self.n_sat, -1, dtype=np.int64)))
        """:meth:`_gate_open`'s answer without a gate: every chain closed, no nearest."""
        if config.wrench.contact_gate:
            alpha = lowpass_alpha(contact_cutoff_hz(config), config.loop.rate_hz)
            held = math.ceil(sample_every_cycles(config.sensor.sample_rate_hz,
                                                 config.loop.rate_hz)) - 1
            self.gate = ContactGate(self.n_sat, config.wrench.contact_gate_margin_m,
                                    hold_cycles_for(config.sensor.delay_cycles + held, alpha))
        self.contact_fits: dict[tuple[int, int], HuntCrossleyFit] = {}
        """Per pair of bodies (a < b), its contact's identified Hunt–Crossley law
        (``[wrench] contact_force = "identified"``)."""
        self._contact_kinematics: list[dict[tuple[int, int], tuple[float, float]]] = []
        """Per recent cycle (newest last), each touching pair's (depth m, depth rate m/s)
        from the mockups' boxes at their FK poses: the readings arrive delayed."""
        self._kinematics_kept = 2 + max((arm.processor.max_age_cycles for arm in self.arms),
                                        default=0)
        """How many cycles of them are kept: as many as a reading can be old, and two."""
        self.rail_arms = [arm for arm in self.arms if getattr(arm, "rail_servo", None)]
        """The arms on a rail (app/sim/rail_rig.py), in robot order."""
        self.recorder = self._recorder(config.loop.telemetry_capacity)
        self._tail_fusable = (self.mode == "hil" and 0 < len(self.arms) <= 2
                              and config.capture is None and not self.rail_arms)
        """Whether a cycle's tail can be the fused call (:meth:`_fused_tail`) in this
        setting: one or two fixed arms, no capture (so no docked compound either)."""
        self.telemetry = self.recorder.buffer
        self.columns = self.telemetry.columns
        self.status = "idle"
        self.safety_stop: dict | None = None
        self.cycles = 0
        # the compute time of the last telemetry_capacity cycles (a ring: a web run is long)
        self._cycle_time_ns = np.zeros(config.loop.telemetry_capacity, dtype=np.int64)
        self.applied_force_R = np.zeros((self.n_sat, 3))
        self.applied_torque_B = np.zeros((self.n_sat, 3))
        self.true_force_R = np.zeros((self.n_sat, 3))
        self.compound: Compound | None = None  # a docked pair, once captured
        self._compound_y: tuple[np.ndarray, np.ndarray] | None = None  # (now, next) rows
        self._leads = np.zeros(0)
        """(L,) the arms' distinct leads > 0 [s], in order (set by :meth:`prepare`)."""
        self._lead_slot: dict[float, int] = {}
        """Each of ``_leads``' index there."""
        self._ahead: tuple[np.ndarray, np.ndarray] | None = None
        """(the ODS state the last step made, the states each of ``_leads`` after it): the
        arms' predictions, worked out in the step's call (:meth:`_predicted`)."""
        self.capture_event: dict | None = None
        self.scaling = scaling_of(config)
        self.gnc = self._gnc_params()
        self.gnc_states = [GncState() for _ in self.gnc]
        self.gnc_wrench = np.zeros((self.n_sat, 6))
        """Each satellite's own GNC wrench of the cycle, orbit units: force in R, torque in
        body axes (zeros without a GNC)."""
        self._rest_fusable = (len(self.arms) == 1 and not self.coupling.enabled
                              and self.gate is None and not self.gnc)
        """Whether a cycle from its F/T chain on can be one compiled call
        (:meth:`_fused_rest`): one arm, its chain's output the ODS input as it is."""
        self._final_recorded_at = -1
        self._sensed_before = False  # the F/T chains ran in a run-up before t = 0
        self.snapshot_at_s: float | None = None
        """When set: at the first cycle that starts at or after this time, the loop keeps a
        copy of its whole state in ``snapshot`` (app/runs/uncertainty.py replays from it)."""
        self.snapshot: Emulator | None = None
        self._shared: dict[int, object] | None = None  # copy_state's, found when first used
        self._load_kernels()

    # --- the cycle ------------------------------------------------------------------------

    def step(self) -> None:
        """One control cycle (paper Fig. 3): the physical interaction on the actual mockups
        (contact, hand); each arm's F/T reading, its processing and the coupling into the
        ODS input; the satellites' own GNC; the ODS step and the telemetry row; a capture
        latch; then each arm's target (where its satellite will be one loop lag later,
        through the frame transformation), the VFDM and the servo. In ideal mode there
        are no arms: the contact acts between the ODS poses."""
        if self.status == "idle":
            self.prepare()
        if self.status != "running":
            return
        if (self.snapshot_at_s is not None and self.snapshot is None
                and self.ods.t_s >= self.snapshot_at_s - 1e-9):
            self.snapshot = self.copy_state()
        t0 = time.perf_counter_ns()
        t_s = self.ods.t_s
        self.hand.update(t_s)
        bodies = self.bodies_W()  # hil: the actual mockups (arm FK); ideal: the ODS poses
        if not self._tracking(bodies):
            return
        external_W = self.interaction.wrenches_W(bodies, t_s)  # contact + operator's hand
        self.true_force_R = external_W[:, :3].dot(self._R_W_R_c)  # `@ self.R_W_R`
        fused = (self._fused_rest(bodies, external_W)  # None: the stages below (one arm, no
                 if self._rest_fusable else None)  # passivity, no gate: one compiled call)
        if fused is None:
            force_R, torque_B = self.ods_input(bodies, external_W,  # F/T chains + coupling
                                               self.true_force_R)
            if not self._within_sensor_range():
                return
            own = self.own_actuation()  # the satellites' GNC: thrusters, wheels (not sensed)
            if own is not None or not self._fused_tail(force_R, torque_B):  # (else the
                # tail below in one compiled call, on the same numbers)
                y_next, force_R, torque_B = self.ods_advance(force_R, torque_B, own)  # ODS
                self.applied_force_R, self.applied_torque_B = force_R, torque_B
                self._record()
                self.ods.commit(y_next, self.dt_s)
                self._capture()
                if own is not None:  # the prediction holds the whole input, own actuation
                    force_R, torque_B = force_R + own[0], torque_B + own[1]
                predicted = self._predicted(force_R, torque_B) if self.arms else ()  # a lead
                for arm, y_ahead in zip(self.arms, predicted, strict=True):  # TCP target
                    arm.command_towards(y_ahead)  # (where the satellite will be) -> VFDM
                    if arm.servo.stopped:  # -> servo
                        self._safety_stop(arm, arm.servo.reason)
        elif not fused:  # a reading at the sensor's range stopped the run
            return
        self._cycle_time_ns[self.cycles % len(self._cycle_time_ns)] = time.perf_counter_ns() - t0
        self.cycles += 1

    @property
    def cycle_time_ns(self) -> np.ndarray:
        """The compute time of each cycle (ns): all of them in a run that fits the
        telemetry capacity (a headless run), else the last telemetry_capacity, unordered."""
        return self._cycle_time_ns[:min(self.cycles, len(self._cycle_time_ns))]

    def bodies_W(self) -> Bodies:
        """Where the bodies that touch are: the actual mockups in hil, the ODS's in ideal."""
        if self.mode == "hil":
            return actual_bodies(self.T_W_R, self.ods, self.arms)
        return ods_bodies(self.T_W_R, self.ods)

    def _tracking(self, bodies: Bodies) -> bool:
        """Whether every arm still shows its satellite: the actual mockup within
        ``[loop] max_tracking_error_m`` / ``_rad`` of the ODS pose; if not, a stop."""
        if not self.arms:
            return True
        loop, errors = self.config.loop, self._tracking_out
        k = tracking_errors(self.T_W_R, self.ods.y, self._carried, bodies.T_W_C,
                            loop.max_tracking_error_m, loop.max_tracking_error_rad, errors)
        if k < 0:
            return True
        d_m, d_rad = errors[k]
        self._safety_stop(self.arms[k], tracking_stop_reason(
            d_m, d_rad, loop.max_tracking_error_m, loop.max_tracking_error_rad))
        return False

    def _within_sensor_range(self) -> bool:
        """``[loop] stop_at_sensor_range``: a raw F/T force reading at the sensor's range
        stops the run: the contact pushes harder than the sensor measures, the ODS gets
        less than the mockups exchange, and the arms would press them on blind."""
        if not self.config.loop.stop_at_sensor_range:
            return True
        limit = self.config.sensor.range_force_N
        for arm in self.arms:
            raw = arm.last_raw_S  # three scalar tests: an array call costs more here
            if abs(raw[0]) >= limit or abs(raw[1]) >= limit or abs(raw[2]) >= limit:
                self._range_stop(arm)
                return False
        return True

    def _range_stop(self, arm: ArmRig) -> None:
        """The stop of :meth:`_within_sensor_range` at arm's reading."""
        self._safety_stop(arm, f"F/T force reading at the sensor's "
                               f"{self.config.sensor.range_force_N:g} N range: the contact "
                               f"pushes harder than it can measure")

    def ods_input(self, bodies: Bodies, external_W: np.ndarray,
                  true_force_R: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """What the ODS receives: each carried satellite the wrench its arm's F/T chain
        measured, the others the external wrench exactly; then the coupling (passivity).
        ``true_force_R``: the external force in R if already at hand (not written)."""
        force_R = (external_W[:, :3] @ self.R_W_R if true_force_R is None
                   else true_force_R.copy())
        torque_B = np.zeros((self.n_sat, 3))
        for i in self._uncarried:  # (as _unsensed_input, written out: every cycle)
            torque_B[i] = body_torque_B(external_W[i], bodies.T_W_C[i])
        # the gate lifts the arms' deadbands and names the contacts their estimate takes:
        # without an arm (an ideal run) it has nothing to act on
        near, nearest = self._gate_open(bodies) if self.arms else (None, None)
        first_cycle = self.cycles == 0 and not self._sensed_before
        any_near = False
        for arm in self.arms:  # its F/T chain's output into its satellite's rows
            gate_open = bool(near[arm.satellite])
            any_near |= gate_open
            arm.sense_rows(external_W, bodies, self.R_W_R, self.dt_s, first_cycle, gate_open,
                           force_R, torque_B)
        self.consistent_pairs = []
        if any_near or (self.arms and self._uncarried and near.any()):
            self._contact_estimate(force_R, torque_B, near, nearest, bodies)
        return self.coupling.ods_input(force_R, torque_B, self.ods, bodies, self.R_W_R)

    def _unsensed_input(self, bodies: Bodies, external_W: np.ndarray,
                        true_force_R: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`ods_input` before the F/T chains: (force in R, torque in B) with every
        satellite's external wrench exactly; the chains' rows are written over."""
        force_R = (external_W[:, :3] @ self.R_W_R if true_force_R is None
                   else true_force_R.copy())
        torque_B = np.zeros((self.n_sat, 3))
        for i in self._uncarried:
            torque_B[i] = body_torque_B(external_W[i], bodies.T_W_C[i])
        return force_R, torque_B

    def _contact_estimate(self, force_R: np.ndarray, torque_B: np.ndarray, near: np.ndarray,
                          partner: np.ndarray, bodies: Bodies) -> None:
        """While gates are open, in place: the pairs of carried mockups that touch only
        each other and whose sensors agree with Newton's third law (app/sim/contact_gate.py)
        are fused (``[wrench] fuse_pair_contact``); with ``contact_estimator``, each
        mockup in one contact (such a pair, or alone with a body no arm carries) gets the
        contact-aware estimate (app/sim/contact_estimator.py). Reads the measured forces,
        the mockups' poses (forward kinematics), their known boxes and the configuration."""
        wrench = self.config.wrench
        if not (wrench.fuse_pair_contact or wrench.contact_estimator):
            return
        alone = self.gate.alone
        pairs = [(a, b) for a, b in contact_pairs(near, partner, alone, self._is_carried)
                 if newton_consistent(force_R[a], force_R[b],
                                      self._force_cov_R(a) + self._force_cov_R(b))]
        self.consistent_pairs = pairs
        fuse = wrench.fuse_pair_contact
        if fuse:
            fuse_pair_forces(force_R, pairs)
        if not wrench.contact_estimator:
            return
        carried, partners = self._is_carried.tolist(), partner.tolist()  # a few bodies
        single = [s for s, (gate_open, by_itself) in enumerate(zip(near.tolist(),
                                                                    alone.tolist(), strict=True))
                  if gate_open and by_itself and carried[s] and partners[s] >= 0
                  and not carried[partners[s]]]
        contact = self.lab_geometry
        frames, no_pull = contact.frames, wrench.contact_no_pull
        identified = wrench.contact_force == "identified"
        # each mockup with whether the identified law may replace its normal force: a
        # fused pair's members (one sample, one law per pair) and the single contacts
        mockups = [(s, fuse) for pair in pairs for s in pair] + [(s, True) for s in single]
        # ndarray.dot instead of `@`: the same BLAS call (dot kernel, gemv) with less
        # overhead; on a C-ordered copy of the rotation (`@` reads the view in place)
        R_W_R = self._R_W_R_c
        model_N: dict[tuple[int, int], float] = {}
        for s, may_identify in mockups:
            p = partners[s]
            a, b = (s, p) if s < p else (p, s)
            frame = frames.get((a, b))
            if frame is None:
                continue
            normal_W, point_W = frame
            if s == a:
                normal_W = -normal_W  # the contact pushes a along −n, b along +n
            T_W_C = bodies.T_W_C[s]
            force_W = R_W_R.dot(force_R[s])
            if identified and may_identify:
                f_n = float(force_W.dot(normal_W))
                if (a, b) not in model_N:  # a fused pair: one sample, one law
                    model_N[(a, b)] = self._identified_normal_force(a, b, s, f_n)
                force_W = force_W + (model_N[(a, b)] - f_n) * normal_W
            f_W, t_W = contact_wrench_W(force_W, normal_W, point_W,
                                        T_W_C[:3, 3], contact.friction(a, b), no_pull)
            force_R[s] = f_W.dot(R_W_R)
            torque_B[s] = t_W.dot(T_W_C[:3, :3])

    def _force_cov_R(self, s: int) -> np.ndarray:
        """(3, 3) the filtered force noise covariance of satellite s's chain, in R (the
        calibration's estimate)."""
        arm = self.arms[self._arm_of[s]]
        R_R_S = self.R_W_R.T.dot(arm.mockup_state_W()[0][:3, :3])  # `@`'s gemm, less overhead
        return arm.processor.filtered_force_cov(R_R_S)

    def _gate_open(self, bodies: Bodies) -> tuple[np.ndarray, np.ndarray]:
        """((N,) whether each body's chain lets a contact below the deadband through,
        (N,) its nearest body or -1): :mod:`app.sim.contact_gate`; all closed without
        ``[wrench] contact_gate``."""
        if self.gate is None:
            return self._gate_closed
        identified = self.config.wrench.contact_force == "identified"
        geometry, gate = self.lab_geometry, self.gate
        if geometry.apart(bodies.T_W_C, gate.margin_m):  # free flight: nothing to measure
            if identified:
                self._keep_contact_kinematics({})
            return gate.update_apart(), gate.partner
        clearance, nearest, crowd = geometry.clearances(bodies.T_W_C, gate.margin_m)
        if identified:
            self._record_contact_kinematics(clearance, nearest, bodies)
        return gate.update(clearance, nearest, crowd), gate.partner

    def _record_contact_kinematics(self, clearance: np.ndarray, nearest: np.ndarray,
                                   bodies: Bodies) -> None:
        """This cycle's (depth, depth rate) of each overlapping pair, from the signed
        distance of the mockups' boxes at their FK poses and their FK velocities at the
        contact point along its normal (ḋ > 0 approaching); kept for as many cycles as a
        reading can be old."""
        frames = self.lab_geometry.frames
        now = {}
        v_W, w_W, T_W_C = bodies.v_W, bodies.w_W, bodies.T_W_C
        clear, near = clearance.tolist(), nearest.tolist()  # a few bodies: plain values
        v_l = w_l = None  # the velocities as floats, once a pair overlaps
        for a in range(self.n_sat):
            b = near[a]
            if b <= a or clear[a] >= 0.0 or (a, b) not in frames:
                continue
            if v_l is None:
                v_l, w_l = v_W.tolist(), w_W.tolist()
            n, p = frames[(a, b)]
            p = p.tolist()  # a few 3-vectors: plain floats, the same operations
            v_a = point_velocity_floats(v_l[a], w_l[a],
                                        minus3_floats(p, T_W_C[a][:3, 3].tolist()))
            v_b = point_velocity_floats(v_l[b], w_l[b],
                                        minus3_floats(p, T_W_C[b][:3, 3].tolist()))
            now[(a, b)] = (-clear[a], float(np.array(minus3_floats(v_a, v_b)).dot(n)))
        self._keep_contact_kinematics(now)

    def _keep_contact_kinematics(self, now: dict[tuple[int, int], tuple[float, float]]) -> None:
        """Append one cycle's (depth, depth rate) per overlapping pair to the history,
        which keeps as many cycles as a reading can be old."""
        history = self._contact_kinematics
        history.append(now)
        if len(history) > self._kinematics_kept:
            del history[0]

    def _identified_normal_force(self, a: int, b: int, s: int, f_n: float) -> float:
        """The normal force of pair (a, b) by its identified law (app/sim/
        contact_identification.py), given body s's measured normal force ``f_n`` (N, >0
        pushing s): the fit takes the sample at the depth and rate of the cycle the
        reading was taken in and returns its law's force there."""
        age = self.arms[self._arm_of[s]].sensor.age_cycles
        history = self._contact_kinematics
        depth, rate = (history[-1 - age].get((a, b), (0.0, 0.0))
                       if len(history) > age else (0.0, 0.0))
        fit = self.contact_fits.get((a, b))
        if fit is None:  # the pair's first sample (not a new fit built every cycle)
            fit = self.contact_fits[(a, b)] = HuntCrossleyFit()
        fit.update(depth, rate, f_n)
        return fit.predict(depth, rate)

    def _gnc_params(self) -> list[tuple[int, GncParams, int | None]]:
        """(satellite, its GNC's parameters in orbit units, the satellite its waypoints are
        relative to or None) for each satellite with one."""
        W = self.ods.params.orbit_rate_radps / self.scaling.time
        p, names = self.ods.params, [s.name for s in self.config.satellites]
        return [(i, GncParams.from_config(sat.gnc, p.mass_kg[i], p.inertia_kgm2[i], W),
                 None if sat.gnc.relative_to is None else names.index(sat.gnc.relative_to))
                for i, sat in enumerate(self.config.satellites) if sat.gnc is not None]

    def own_actuation(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The satellites' own (force in R, torque in body axes) over this cycle in
        ODS-input units (None when no satellite has a GNC): each GNC reads its satellite's
        ODS state in orbit units and commands in orbit units (app/sim/gnc.py), kept in
        ``gnc_wrench``; the scaling turns that into the ODS's input (F_o k_T² / (k_L
        force_scale), τ_o k_T² / torque_scale)."""
        if not self.gnc:
            return None
        sc, W_lab = self.scaling, self.ods.params.orbit_rate_radps
        dt_orbit_s = sc.time * self.dt_s
        for k, (i, params, j) in enumerate(self.gnc):
            nav = navigation(self.ods.y[i], self.ods.t_s, sc, W_lab)
            target = None if j is None else navigation(self.ods.y[j], self.ods.t_s, sc, W_lab)
            self.gnc_states[k], force_R, torque_B = gnc_step(params, self.gnc_states[k], nav,
                                                             dt_orbit_s, target)
            self.gnc_wrench[i, :3], self.gnc_wrench[i, 3:] = force_R, torque_B
        return sc.ods_force(self.gnc_wrench[:, :3]), sc.ods_torque(self.gnc_wrench[:, 3:])

    def ods_advance(self, force_R: np.ndarray, torque_B: np.ndarray,
                    own: tuple[np.ndarray, np.ndarray] | None = None,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(next ODS state, external force, torque the ODS received over the cycle): Eqs.
        1-7 by RK4 under the cycle's input plus the satellites' own actuation ``own``
        (ODS-input units, :meth:`own_actuation`); in an ideal run, a cycle that starts or
        ends in contact has the contact law integrated within it (:mod:`app.sim.reference`),
        the own actuation acting in every sub-step; a docked pair moves as one body."""
        total = (force_R, torque_B) if own is None else (force_R + own[0], torque_B + own[1])
        if self._lead_slot and self.compound is None:  # and the arms' predictions from it
            y_next, ahead = self.ods.advance_and_ahead(*total, self.dt_s, self._leads)
            self._ahead = (y_next, ahead)
        else:  # (a compound's step rewrites y_next: its predictions come after it)
            y_next = self.ods.advance(*total, self.dt_s)
        if self.mode == "ideal" and (self.interaction.contact_active
                                     or self._overlap(y_next)):
            y_next, force_R, torque_B = substepped_advance(
                self.ods, self.interaction, self.T_W_R, self.ods.t_s, self.dt_s,
                self.config.loop.reference_substeps, own)
            self.true_force_R = force_R  # no sensor in an ideal run: the ODS gets the truth
        if self.compound is not None:  # the docked pair moves as one body
            y_next = self._advance_compound(y_next, *total)
        return y_next, force_R, torque_B

    def _predicted(self, force_R: np.ndarray, torque_B: np.ndarray) -> list[np.ndarray]:
        """Each arm's ODS state ``lead_s`` ahead of the committed one under the cycle's
        whole input (force_R, torque_B: app/sim/compensation.py predicted_state), once per
        lead: the states the ODS step worked out in its call (:meth:`ods_advance`) while
        the committed state is the one they start from (a capture rewrites it: then anew)."""
        ahead, self._ahead = self._ahead, None
        from_step = ahead is not None and ahead[0] is self.ods.y
        made: dict[float, np.ndarray] = {}
        for arm in self.arms:
            lead = arm.lead_s
            if lead not in made:
                made[lead] = (ahead[1][self._lead_slot[lead]]
                              if from_step and lead in self._lead_slot
                              else predicted_state(self.ods, force_R, torque_B, lead))
        return [made[arm.lead_s] for arm in self.arms]

    def _fused_tail(self, force_R: np.ndarray, torque_B: np.ndarray) -> bool:
        """The rest of a cycle without own actuation, as :meth:`step` reads it (the ODS
        step and its predictions, the telemetry row, each arm's command), in one compiled
        call (app/sim/cycle_tail.py) where it is those stages and nothing else
        (:meth:`_tail_commands`); False, with nothing done, where it is not."""
        tail = self._tail_commands()
        if tail is None:
            return False
        targets, commands = tail
        rows = []
        for arm in self.arms:
            _, T_W_C, v_W, _ = arm.mockup_state_W()
            rows.append((T_W_C, v_W, arm.last_raw_S, arm.last_processed))
        self.applied_force_R, self.applied_torque_B = force_R, torque_B
        ods_out = np.empty((1 + len(self._leads),) + self.ods.y.shape)
        at, *done = _call_tail(_tail_head(self.ods, self.recorder, force_R, torque_B,
                                          self.dt_s, self._leads, ods_out, self.true_force_R),
                               rows, targets, commands)
        self._tail_done(at, ods_out, commands, done)
        return True

    def _fused_rest(self, bodies: Bodies, external_W: np.ndarray) -> bool | None:
        """A one-arm cycle from its F/T chain on, as :meth:`step` reads it, in one compiled
        call (app/sim/cycle_tail.py :func:`sensed_tail_one_arm`) where the chain's output
        is the ODS input as it is (``_rest_fusable``, which the caller checks: no passivity,
        no contact gate, no GNC), the chain is
        one call (:meth:`ArmRig.fused_sense`) and the tail one too (:meth:`_tail_commands`):
        True when the cycle ran, False when a reading at the sensor's range stopped it
        (``[loop] stop_at_sensor_range``); None, with nothing done, where it is not."""
        arm = self.arms[0]
        if not arm.fused_sense():
            return None
        tail = self._tail_commands()
        if tail is None:
            return None
        (target,), (command,) = tail
        force_R, torque_B = self._unsensed_input(bodies, external_W, self.true_force_R)
        self.consistent_pairs = []
        first_cycle = self.cycles == 0 and not self._sensed_before
        sensed = np.empty(arm_sense.OUT_SIZE)
        range_N = (self.config.sensor.range_force_N if self.config.loop.stop_at_sensor_range
                   else 0.0)
        ods_out = np.empty((1 + len(self._leads),) + self.ods.y.shape)
        at, *done = _call_rest(arm, external_W, bodies, first_cycle, self.R_W_R, sensed,
                               range_N, _tail_head(self.ods, self.recorder, force_R, torque_B,
                                                   self.dt_s, self._leads, ods_out,
                                                   self.true_force_R), target, command)
        arm_sense.sensed(arm, sensed)
        if at == RANGE_STOP:
            self._range_stop(arm)
            return False
        self.applied_force_R, self.applied_torque_B = force_R, torque_B
        self._tail_done(at, ods_out, [command], done)
        return True

    def _tail_commands(self) -> tuple[list[int], list[tuple]] | None:
        """(each arm's row of the fused tail's ODS output, its
        :meth:`ArmRig.fused_command_args`) where the tail can be one compiled call
        (``_tail_fusable``: a hil run of one or two fixed arms, no capture to check, no
        rail; a recorder of these arms; and each arm's command fused, its lead none or
        among the ODS step's); None where not."""
        arms, rec = self.arms, self.recorder
        if not (self.fuse_tail and self._tail_fusable) or rec.n_arms != len(arms) \
                or rec.n_rails:  # (a recorder of other arms: the stages' error)
            return None
        commands, targets = [], []
        for arm in arms:  # its target: the step's state (no lead) or its prediction
            target = 0 if arm.lead_s <= 0.0 else 1 + self._lead_slot.get(arm.lead_s, -2)
            args = None if target < 0 else arm.fused_command_args()
            if args is None:
                return None
            commands.append(args)
            targets.append(target)
        return targets, commands

    def _tail_done(self, at: int, ods_out: np.ndarray, commands: list[tuple],
                   done: list) -> None:
        """After a fused tail's call (its row's index ``at``, each arm's VFDM scale and
        servo stop code in ``done``): the row and the ODS state taken, each arm's command
        (:meth:`ArmRig.commanded`), a stop where its servo stopped."""
        if at < 0:  # a shape that does not fit the row: the stages' error, nothing written
            self._record()
            raise RuntimeError("the fused tail's telemetry row did not fit, the stages' did")
        self.recorder.buffer.commit()
        self.ods.commit(ods_out[0], self.dt_s)
        for k, arm in enumerate(self.arms):
            slot, out = commands[k][7], commands[k][-1]
            arm.commanded(done[2 * k], done[2 * k + 1], slot, out)
            if arm.servo.stopped:
                self._safety_stop(arm, arm.servo.reason)

    def _advance_compound(self, y_next: np.ndarray, force_R: np.ndarray,
                          torque_B: np.ndarray) -> np.ndarray:
        """The compound's step under its members' summed wrench (app/sim/capture.py),
        spread over the members' rows of y_next."""
        row = self._compound_y[0]
        F, tau = compound_wrench(self.compound, row, force_R, torque_B)
        p = self.ods.params
        params = OdsParams(p.orbit_rate_radps, np.array([self.compound.mass_kg]),
                           self.compound.inertia_kgm2[None, :], p.gravity_gradient,
                           p.force_scale, p.torque_scale)
        row_next = rk4_step(params, row[None, :], F[None, :], tau[None, :], self.dt_s)[0]
        y_next = y_next.copy()
        spread(self.compound, row_next, p.orbit_rate_radps, y_next)
        self._compound_y = (row, row_next)
        return y_next

    def _capture(self) -> None:
        """After a step: a docked pair becomes one body once inside its capture envelope
        (``[capture]``), touching in this cycle's contact (hil: the actual mockups; ideal:
        the ODS bodies) unless ``require_contact`` is off; from the next step on the ODS
        moves it as one."""
        cap = self.config.capture
        if self.compound is not None:
            self._compound_y = (self._compound_y[1], self._compound_y[1])
            return
        if cap is None:
            return
        c, t = self.config.satellite_index(cap.chaser), self.config.satellite_index(cap.target)
        if cap.require_contact and frozenset((c, t)) not in self.interaction.touching:
            return
        p = self.ods.params
        p_rel, v_rel, angle, rate = relative_state(self.ods.y, c, t, p.orbit_rate_radps)
        miss = float(np.linalg.norm(p_rel - np.asarray(cap.mated_offset_m)))
        speed = float(np.linalg.norm(v_rel))
        if (miss > cap.position_tolerance_m or speed > cap.velocity_tolerance_mps
                or angle > cap.attitude_tolerance_rad or rate > cap.rate_tolerance_radps):
            return
        self.compound, row = join(self.ods.y, (c, t), p.mass_kg, p.inertia_kgm2,
                                  p.force_scale, p.torque_scale, p.orbit_rate_radps)
        self._ahead = None  # the state the predictions started from is rewritten here
        spread(self.compound, row, p.orbit_rate_radps, self.ods.y)
        self._compound_y = (row, row)
        self.interaction.contact.exclude(c, t)
        if self._drawn_boxes is not None:
            self._drawn_boxes.exclude(c, t)
        self._drift_after_capture({c, t})
        self.capture_event = {"t_s": float(self.ods.t_s), "position_miss_m": miss,
                              "relative_speed_mps": speed, "relative_angle_rad": angle,
                              "relative_rate_radps": rate}

    def _drift_after_capture(self, pair: set[int]) -> None:
        """A GNC flying relative to the satellite it has just been captured with has
        nothing left to fly to (its reference is part of its own body now): it goes into
        free drift, as a chaser's thrusters are inhibited at capture."""
        for k, (i, _, j) in enumerate(self.gnc):
            if j is not None and {i, j} == pair:
                self.gnc_states[k] = replace(self.gnc_states[k], drifting=True,
                                             force_B_N=np.zeros(3), torque_B_Nm=np.zeros(3))

    def _overlap(self, y: np.ndarray) -> bool:
        """Whether any two bodies overlap in the ODS state y."""
        T_W_C, v_unused = np.empty((self.n_sat, 4, 4)), np.empty((self.n_sat, 3))
        ods_states_W(self.T_W_R, y, T_W_C, v_unused)  # the poses ods_bodies would give
        return self.interaction.contact.overlapping(T_W_C)

    def _record(self) -> None:
        """Append the telemetry row of the current state."""
        arms = []
        for arm in self.arms:
            _, T_W_C, v_W, _ = arm.mockup_state_W()
            arms.append((T_W_C, v_W, arm.servo.state.q_rad, arm.last_raw_S,
                         arm.last_processed))
        rails = (np.array([arm.rail_row() for arm in self.rail_arms]) if self.rail_arms
                 else None)
        self.recorder.record(self.ods.t_s, self.ods.y, self.applied_force_R,
                             self.applied_torque_B, arms, self.true_force_R,
                             self.gnc_wrench if self.gnc else None, rails)

    def _recorder(self, capacity: int) -> Recorder:
        return Recorder(self.n_sat, len(self.arms), capacity, self.T_R_W,
                        self.ods.params.orbit_rate_radps,
                        [arm.index + 1 for arm in self.rail_arms])

    def _safety_stop(self, arm: ArmRig, reason: str) -> None:
        self.status = "safety_stop"
        self.safety_stop = {"robot": arm.index + 1, "t_s": self.ods.t_s, "reason": reason}

    def copy_state(self, capacity: int = 100) -> Emulator:
        """A deep copy of the loop's whole state (arms, sensors and their random generators,
        filters, gate, coupling, ODS, hand) that steps on exactly as this one would, with a
        fresh telemetry recorder of ``capacity`` rows instead of this one's (and no
        snapshot of its own). What is never written (SHARED_TYPES: the configuration, the
        kinematic models) is shared, not copied; the list of them is found once per loop
        copied (a snapshot is copied once per replicate)."""
        if self._shared is None:
            self._shared = shared_constants(self)
        recorder = self._recorder(capacity)
        memo = dict(self._shared)
        memo.update({id(self.recorder): recorder, id(self.telemetry): recorder.buffer,
                     id(self.columns): recorder.buffer.columns,
                     id(self._cycle_time_ns): np.zeros(capacity, dtype=np.int64),
                     id(self.snapshot): None, id(self._shared): None,
                     id(self._gate_closed): self._gate_closed})  # (read-only, shared)
        twin = copy.deepcopy(self, memo)
        twin.snapshot_at_s = None
        return twin

    # --- commands -------------------------------------------------------------------------

    def post(self, command: Command) -> None:
        """Queue a Push / HandAnchor; it takes effect at the start of the next cycle."""
        self.hand.post(command)

    # --- start-up -------------------------------------------------------------------------

    def prepare(self, settle_s: float | None = None, tick=None) -> None:
        """Move every arm to its start pose, calibrate its F/T sensor, start the clock.

        The start posture is found by the VFDM itself (run on its virtual model only until
        converged); the arm then makes a smooth joint move there within half its speed
        limits, rests for `settle_s` (default ``[wrench] calibration_s``) while the sensor
        readings are averaged for the payload calibration (bias with the known mockup mass
        and COM, as the paper's lab did).
        ``tick``: called now and then while it works (a supervisor's heartbeat).
        """
        tick = tick or (lambda: None)
        if settle_s is None:
            settle_s = self.config.wrench.calibration_s
        steps = int(self.config.loop.approach_timeout_s * self.config.loop.rate_hz)
        run_up = self._run_up()
        for arm in self.arms:
            q = self._start_posture(arm, self.ods.y, steps, tick)
            if self.config.compensation.enabled:  # the lag where the run begins
                lead = self.config.compensation.lead_s
                arm.lead_s = (lag_model(self.config, arm.T_F_C, q, tick,
                                        self.config.robots[arm.index],
                                        _carriage_at(arm)).lead_s
                              if lead is None else lead)
            if run_up is not None:  # the run-up begins v0·run_up_s/2 before it
                q = self._start_posture(arm, run_up(-self.config.loop.run_up_s), steps,
                                        tick, note=(
                    f" (its {self.config.loop.run_up_s:g} s run-up begins there, "
                    f"v0·run_up_s/2 before the initial pose; loop.run_up_s = 0 starts at "
                    f"the initial pose)"))
            arm.q_start_rad = q
            tick()
            arm.move_to(q, self.dt_s)
            tick()
        leads = sorted({arm.lead_s for arm in self.arms if arm.lead_s > 0.0})
        self._leads, self._lead_slot = np.array(leads), {t: k for k, t in enumerate(leads)}
        rest = {arm.index: [] for arm in self.arms}
        tick()
        for k in range(int(round(settle_s / self.dt_s))):
            for arm in self.arms:
                rest[arm.index].append(arm.rest_reading())
            if k % 100 == 99:
                tick()
        for arm in self.arms:
            if arm.servo.stopped:
                self._safety_stop(arm, arm.servo.reason)
                return
            arm.calibrate(np.array(rest[arm.index]))
        if run_up is not None:
            if not self._run_up_arms(run_up, tick):
                return
            self._sensed_before = True
        self.status = "running"

    def _start_posture(self, arm: ArmRig, y: np.ndarray, steps: int, tick,
                       note: str = "") -> np.ndarray:
        """The joints that put ``arm``'s mockup on its satellite in state ``y``, or
        StartPoseError (``note`` says which pose it was)."""
        q, error_m = arm.solve_start_posture(arm.tcp_target_B(y), steps, tick)
        if q is None:
            raise StartPoseError(
                f"robot {arm.index + 1}: start pose of satellite "
                f"{self.config.satellites[arm.satellite].name!r} not reached "
                f"(error {error_m:.4f} m): is it within reach?{note}")
        return q

    def _run_up(self):
        """τ ↦ the satellites' state at τ ≤ 0 of the flying start (app/sim/run_up.py), or
        None: an ideal run, ``[loop] run_up_s = 0``, or satellites that start at rest."""
        T = self.config.loop.run_up_s
        if not self.arms or T <= 0.0:
            return None
        y0 = self.ods.y.copy()
        zeros = np.zeros((self.n_sat, 3))
        omega_rel_B = relative_rates(y0, self.ods.advance(zeros, zeros, self.dt_s), self.dt_s)
        if not runs_up(y0, omega_rel_B):
            return None

        def state(tau_s: float) -> np.ndarray:
            if tau_s > 0.0:  # a lead past t = 0: the ODS's own course, nothing applied
                return self.ods.advance(zeros, zeros, tau_s)
            return run_up_state(y0, omega_rel_B, T, tau_s)
        return state

    def _run_up_arms(self, run_up, tick) -> bool:
        """Drive every arm along the run-up as the cycle does: its F/T chain reads and
        processes (nothing touches; what it measures goes nowhere, but its filters and
        its estimate of the mockup's acceleration are those of a moving arm at t = 0),
        then VFDM → servo towards the pose its lead asks for. False if a servo stopped
        (a safety stop)."""
        n = int(round(self.config.loop.run_up_s / self.dt_s))
        nothing = np.zeros(6)
        for k in range(1, n + 1):
            tau_s = (k - n) * self.dt_s
            bodies = actual_bodies(self.T_W_R, self.ods, self.arms)
            for arm in self.arms:
                s = arm.satellite
                arm.sense(nothing, bodies.T_W_C[s], bodies.v_W[s], self.R_W_R, self.dt_s,
                          first_cycle=k == 1)
                arm.command(arm.tcp_target_B(run_up(tau_s + arm.lead_s)))
                if arm.servo.stopped:
                    self._safety_stop(arm, arm.servo.reason)
                    return False
            if k % 100 == 0:
                tick()
        return True

    def _load_kernels(self) -> None:
        """Run each compiled kernel once on scratch data, so that numba loads it from its
        cache now rather than in the first timed cycles; the simulation is not touched."""
        ods = OrbitalSimulator(self.ods.params, self.ods.y.copy())
        zeros = np.zeros((self.n_sat, 3))
        ods.step(zeros, zeros, self.dt_s)
        if self.arms:  # the step with the arms' predictions (a lead: compensation on)
            ods.advance_and_ahead(zeros, zeros, self.dt_s, np.array([self.dt_s]))
        scratch = self._recorder(1)
        bodies = ods_bodies(self.T_W_R, ods)
        self.interaction.contact.apart(bodies.T_W_C)  # (and the gate's, on the same model)
        if not self.arms:
            scratch.record(0.0, ods.y, zeros, zeros, [], zeros)
            return
        tracking_errors(self.T_W_R, ods.y, self._carried, bodies.T_W_C, 1.0, 1.0,
                        np.zeros((len(self.arms), 2)))
        rig = build_cell(0, self.config.robots[0], self.config, self.T_W_R,
                        np.random.default_rng(0))
        T_W_F, T_W_C, v_W, _ = rig.mockup_state_W()
        rig.sense(np.zeros(6), T_W_C, v_W, self.R_W_R, self.dt_s, first_cycle=True)
        rig.sense_rows(np.zeros((self.n_sat, 6)), bodies, self.R_W_R, self.dt_s, False, False,
                       zeros.copy(), zeros.copy())  # the cycle's, on its rows
        rig.command(rig.tcp_target_B(ods.y))  # the run-up's
        rig.command_towards(ods.y)  # the cycle's
        scratch.record(0.0, ods.y, zeros, zeros,
                       [(T_W_C, v_W, rig.servo.state.q_rad, rig.last_raw_S,
                         rig.last_processed)] * len(self.arms),
                       zeros, None, np.zeros((len(self.rail_arms), 3)) if self.rail_arms
                       else None)
        command = rig.fused_command_args()  # (None: the servo feedforward's stages)
        if self._tail_fusable and command is not None:  # the tail in one call (_fused_tail)
            n = len(self.arms)
            head = _tail_head(ods, scratch, zeros, zeros.copy(), self.dt_s,
                              np.array([self.dt_s]), np.empty((2,) + ods.y.shape), zeros)
            _call_tail(head, [(T_W_C, v_W, rig.last_raw_S, rig.last_processed)] * n, [1] * n,
                       [command, rig.fused_command_args()][:n])
            if self._rest_fusable and rig.fused_sense():  # the cycle from the chain on
                _call_rest(rig, np.zeros((self.n_sat, 6)), bodies, False, self.R_W_R,
                           np.empty(arm_sense.OUT_SIZE), 1.0, head, 1,
                           rig.fused_command_args())
        for k, robot in enumerate(self.config.robots):
            if robot.rail is not None:  # the rail's kernels too
                rig = build_cell(k, robot, self.config, self.T_W_R, np.random.default_rng(0))
                rig.mockup_state_W()
                rig.command(rig.tcp_target_B(ods.y))
                break

    # --- views for the web app and the metrics ------------------------------------------------

    @property
    def t_s(self) -> float:
        return self.ods.t_s

    @property
    def lab_geometry(self) -> BoxContactModel:
        """The mockups' boxes as the lab knows them (their drawing, ``size_m``): the
        contact gate's clearances, the estimator's frames, μ. The simulated contact's own
        boxes unless a mockup was built another size (``size_error_m``)."""
        return self.interaction.contact if self._drawn_boxes is None else self._drawn_boxes

    @property
    def contact_active(self) -> bool:
        return self.interaction.contact_active

    def satellite_pose_W(self, i: int) -> np.ndarray:
        """ODS pose of satellite i in the lab: T_W_R · T_R_sat."""
        T = np.empty((4, 4))
        satellite_pose(self.T_W_R, self.ods.y, i, T)
        return T

    def mockup_pose_R(self, arm: ArmRig) -> tuple[np.ndarray, np.ndarray]:
        """Actual mockup COM position and attitude (wxyz) in R, from the robot's FK."""
        T_R_C = self.T_R_W @ arm.mockup_state_W()[1]
        return T_R_C[:3, 3], matrix_to_quat(T_R_C[:3, :3])

    # --- running -----------------------------------------------------------------------

    def run(self, duration_s: float, progress=None) -> None:
        """Run until duration_s of scenario time, a safety stop, or stop()."""
        if self.status == "idle":
            self.prepare()
        n = int(round(duration_s / self.dt_s))
        for k in range(n):
            if self.status != "running":
                break
            self.step()
            if progress is not None and k % 500 == 0:
                progress(k, n)
        if self.status == "running":
            self.status = "finished"
        self.record_final()

    def record_final(self) -> None:
        """Record the final state once, whatever ended the run (a run's telemetry ends
        with the state it stopped in; the paced loop of the web app calls this too)."""
        if self.cycles and self._final_recorded_at != self.cycles:
            self._record()
            self._final_recorded_at = self.cycles
