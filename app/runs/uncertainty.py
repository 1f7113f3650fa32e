"""The restitution's uncertainty, from what the lab measures (docs/fidelity-uncertainty.md).

A closed-loop Monte Carlo of the contact window. A hil run keeps a copy of its whole loop
(:meth:`app.sim.loop.Emulator.copy_state`) ``[uncertainty] lead_s`` before the contact
its ideal run predicts. After the run, each replicate steps a copy of it through the very
same :meth:`~app.sim.loop.Emulator.step` (arms, sensors, processing, gate, fusion,
passivity, ODS) until its contact has ended and the velocities after it can be read, with

* fresh sensor noise of the standard deviation each arm's sensor showed at rest during
  the start-up calibration (``ArmRig.rest_sd_S``: measured, not the configured value);
* a fresh draw of the calibration's own bias-estimate error, σ / sqrt(n_rest) per axis;

and its restitution is read by the run's own code (:func:`app.runs.metrics.collision_metrics`).
The replicates' standard deviation is the restitution's, ``restitution_sd``; the 95 %
interval is the run's e ± 1.96 sd. The contact in a replicate is the configured contact
law: the lab's model of its own mockups (their digital twin), not the mockups themselves.

The forecast (:func:`forecast`) is the same Monte Carlo before the arms move: a hil twin
of the run with the sensor's noise off up to the snapshot, replicates with the configured
noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from operator import itemgetter

import numpy as np

from app.config import EmulatorConfig, merge_overrides
from app.runs.metrics import collision_metrics
from app.runs.rendering import rendering_error
from app.sim.compensation import force_lag_s
from app.sim.loop import Emulator, StartPoseError
from app.sim.rotations import skew

__all__ = ["SensorNoise", "add_systematic", "configured_noise", "forecast", "lead_warning",
           "measured_noise", "noisy_bias", "replicate", "restitution_spread", "run_interval",
           "sd_standard_error", "snapshot_time_s", "spread_of_run"]

QUIET_S = 0.05
"""A contact ends once the bodies have been apart this long (app/runs/metrics.py)."""
WAIT_S = 0.02
"""The velocities after a contact are read this long past its window (app/runs/metrics.py)."""
Z95 = 1.959963984540054
"""The two-sided 95 % quantile of the normal distribution."""


@dataclass(frozen=True)
class SensorNoise:
    """One arm's sensor noise as a replicate draws it."""

    sd_S: np.ndarray
    """(6,) per-axis standard deviation of one reading [N, N·m]."""
    bias_sd_S: np.ndarray
    """(6,) standard deviation of the calibration's bias estimate (sd / sqrt(n_rest))."""


def measured_noise(em: Emulator) -> list[SensorNoise] | None:
    """Per arm, the noise its sensor showed at rest during the start-up calibration (None
    before a calibration of two or more readings)."""
    out = []
    for arm in em.arms:
        if arm.rest_sd_S is None or arm.rest_count < 2:
            return None
        sd = np.array(arm.rest_sd_S, dtype=float)
        out.append(SensorNoise(sd, sd / math.sqrt(arm.rest_count)))
    return out


def configured_noise(config: EmulatorConfig) -> list[SensorNoise]:
    """Per arm, the configured sensor noise and the bias error its calibration would leave
    (the forecast's noise: nothing is measured yet)."""
    s = config.sensor
    sd = np.array([s.noise_force_N] * 3 + [s.noise_torque_Nm] * 3, dtype=float)
    n = max(1, int(round(config.wrench.calibration_s * config.loop.rate_hz)))
    return [SensorNoise(sd, sd / math.sqrt(n)) for _ in config.robots]


def expect_measured_noise(em: Emulator, noise: list[SensorNoise]) -> None:
    """Give each arm's calibration the noise covariance its rest readings would show with
    ``noise`` (diagonal: σ_f² per force axis; about the COM, σ_τ² plus the lever arm of
    the force noise, [c]ₓ Σ_f [c]ₓᵀ), and the deadbands that follow from it. The
    forecast's twin calibrates without noise (its bias exact), yet the chain reads the
    measured covariance: the pair fusion's Newton check and the deadbands' noise floor.
    With a zero covariance, the replicates' noisy sensors failed the check on nearly
    every cycle, and the forecast was of a chain without fusion or estimator."""
    for arm, nz in zip(em.arms, noise, strict=True):
        proc = arm.processor
        cal = proc.calibration
        cov_f = np.diag(np.square(nz.sd_S[:3]))
        c = skew(np.asarray(cal.com_F_m, dtype=float))
        cov_t = np.diag(np.square(nz.sd_S[3:])) + c @ cov_f @ c.T
        proc.calibration = replace(cal, force_noise_cov_S=cov_f, torque_noise_cov_S=cov_t)
        proc.set_deadbands()


def snapshot_time_s(config: EmulatorConfig, ideal: dict | None) -> float | None:
    """When a hil run keeps its snapshot: ``[uncertainty] lead_s`` before the ideal run's
    first touch (None without one, or with ``enabled`` off). Negative where the lead is
    longer than the time to the touch: the loop then keeps it at its first cycle, t = 0,
    and the run's metrics say so (:func:`lead_warning`)."""
    if not config.uncertainty.enabled or not ideal or ideal.get("contact_start_s") is None:
        return None
    return float(ideal["contact_start_s"]) - config.uncertainty.snapshot_lead_s


def lead_warning(config: EmulatorConfig, at_s: float | None) -> str | None:
    """The warning for a snapshot time ``at_s`` (:func:`snapshot_time_s`) before t = 0,
    naming the lead asked for and the lead used; None for none."""
    if at_s is None or at_s >= 0.0:
        return None
    lead = config.uncertainty.snapshot_lead_s
    return (f"uncertainty.lead_s = {lead:g} s would put the snapshot at t = {at_s:.3f} s, "
            f"before the run starts: it was taken at t = 0, {lead + at_s:.3f} s before the "
            f"ideal run's first touch")


def replicate(snapshot: Emulator, pair: tuple[int, int], until_s: float,
              noise: list[SensorNoise] | None = None,
              rng: np.random.Generator | None = None, rendering: bool = False) -> dict | None:
    """One replicate of the contact window from ``snapshot`` (left untouched): its
    collision metrics (app/runs/metrics.collision_metrics; None if the pair never touched),
    with ``rendering`` also how far its mockups rendered the contact (Eq. R1, the
    forecast's noise-free twin's).

    It steps until the pair's contact has ended (apart for QUIET_S) and WAIT_S more, a
    stop, or ``until_s``. ``noise``: per arm, draw fresh noise of this size with ``rng``
    and shift each calibration's bias by a fresh draw of its error; None: the snapshot's
    own noise sequence and calibration (the replicate then is the run itself).
    """
    return _replicate(snapshot, pair, until_s, None if noise is None else _draw(noise, rng),
                      noise, rendering)


def _replicate(snapshot: Emulator, pair: tuple[int, int], until_s: float,
               draw: list | None, noise: list[SensorNoise] | None,
               rendering: bool = False) -> dict | None:
    """:func:`replicate` with its draws made (:func:`_draw`; None: the snapshot's own)."""
    dt_s = snapshot.dt_s
    cycles = int(math.ceil((until_s - snapshot.t_s) / dt_s)) + 3
    em = snapshot.copy_state(capacity=max(100, cycles))
    if draw is not None:
        _redraw(em, noise, draw)
    a, b = pair[0] - 1, pair[1] - 1
    after = int(round((QUIET_S + WAIT_S) / dt_s)) + 2
    last_touch = None
    while em.status == "running" and em.t_s < until_s - 1e-9:
        em.step()
        if em.true_force_R[a].any() and em.true_force_R[b].any():
            last_touch = em.cycles
        elif last_touch is not None and em.cycles - last_touch > after:
            break
    em.record_final()
    bodies = {arm.satellite + 1: f"rob{arm.index + 1}" for arm in em.arms}
    rows, index = em.telemetry.rows(), em.telemetry.index
    coll = collision_metrics(rows, index, dt_s, *pair, bodies=bodies)
    if coll is not None and rendering:  # how far the mockups rendered it (Eq. R1)
        coll.update(rendering_error(rows, index, coll, bodies, force_lag_s(em.config),
                                     em.interaction.contact))
    if coll is not None:  # the satellites' velocities (R) as the replicate ends
        coll["velocity_after_mps"] = {
            f"sat{s}": rows[-1, [index[f"sat{s}_v{a}_mps"] for a in "xyz"]].tolist()
            for s in pair}
    return coll


def _draw(noise: list[SensorNoise], rng: np.random.Generator) -> list[tuple]:
    """One replicate's draws from ``rng``, per arm: its sensor's new generator seed and
    its calibration's bias-estimate error (S). Made before the replicate runs, in this
    order, so that replicates run anywhere give the same results."""
    return [(rng.integers(2**63), nz.bias_sd_S * rng.standard_normal(6)) for nz in noise]


def _redraw(em: Emulator, noise: list[SensorNoise], draw: list[tuple]) -> None:
    """Give each arm's sensor a new noise generator and standard deviation, and its
    calibration a new draw of the bias estimate's error (:func:`_draw`)."""
    for arm, nz, (seed, bias_error_S) in zip(em.arms, noise, draw, strict=True):
        arm.sensor.rng = np.random.default_rng(seed)
        arm.sensor.noise_std_S = np.array(nz.sd_S, dtype=float)
        cal = arm.processor.calibration
        arm.processor.calibration = replace(cal, bias_S=cal.bias_S + bias_error_S)


def restitution_spread(snapshot: Emulator, pair: tuple[int, int], until_s: float,
                       noise: list[SensorNoise], replicates: int,
                       rng: np.random.Generator, tick=None, processes: int = 1) -> dict:
    """{"restitution_sd", "replicates", "replicates_with_restitution", "restitutions",
    "velocity_sd_mps"}: the standard deviation (ddof 1) of the replicates' restitutions
    (None with fewer than two), and per satellite of the pair of their velocities (R, per
    axis) as they end, after the contact. ``tick``: called before each replicate (a
    supervisor's heartbeat). ``processes``: how many processes run the replicates
    (app/runs/replicate_pool.py); the results are the same bit for bit."""
    from app.runs.replicate_pool import run_replicates

    draws = [_draw(noise, rng) for _ in range(replicates)]
    values, after = [], []
    for coll in run_replicates(_replicate, (snapshot, pair, until_s), noise, draws,
                               processes, tick):
        values.append(None if coll is None else coll["restitution"])
        if coll is not None and coll["restitution"] is not None:
            after.append(coll["velocity_after_mps"])
    got = [v for v in values if v is not None]
    velocity_sd = None
    if len(after) > 1:
        velocity_sd = {name: np.std([a[name] for a in after], axis=0, ddof=1).tolist()
                       for name in after[0]}
    return {"restitution_sd": float(np.std(got, ddof=1)) if len(got) > 1 else None,
            "replicates": replicates, "replicates_with_restitution": len(got),
            "restitutions": values, "velocity_sd_mps": velocity_sd}


def sd_standard_error(values) -> float | None:
    """The standard error of the sample standard deviation s of ``values`` (None with
    fewer than four): its large-sample form, for any distribution of finite fourth moment,

        Var(s²) ≈ σ⁴ (2 / (n − 1) + κ / n),   SE(s) ≈ (s / 2) √(2 / (n − 1) + κ / n)

    with κ the sample's excess kurtosis (0 for a normal sample: SE(s) ≈ s / √(2 (n − 1))).
    A replicate count sets how well a spread is known: 60 replicates give it to about
    ±9 %, 200 to about ±5 %."""
    x = np.asarray(values, dtype=float)
    n = len(x)
    if n < 4:
        return None
    s = float(np.std(x, ddof=1))
    m2 = float(np.mean((x - x.mean()) ** 2))
    if m2 == 0.0:
        return 0.0
    kappa = float(np.mean((x - x.mean()) ** 4)) / m2**2 - 3.0
    return 0.5 * s * math.sqrt(max(0.0, 2.0 / (n - 1) + kappa / n))


def _rng(config: EmulatorConfig, stream: int) -> np.random.Generator:
    """The replicates' generator: a run's from its seed, apart from the sensors' streams
    (equal runs give equal intervals); the forecast's (``stream`` 2) the same for every
    seed (it is the configuration's, computed before any run: kept once per setting for
    all its seeds, app/runs/forecast_cache.py)."""
    seed = config.loop.seed if stream != 2 else 0
    return np.random.default_rng([seed, 28, stream])


def spread_of_run(em: Emulator, coll: dict | None, tick=None, processes: int = 1) -> None:
    """After a hil run (its ``snapshot`` kept): add ``restitution_sd`` and
    ``restitution_interval_95`` ([e − 1.96 sd, e + 1.96 sd]) to its collision metrics
    ``coll`` (in place; both None where there is no snapshot, no noise measured, or no
    restitution), and ``uncertainty`` (how they were found). ``tick``: called before each
    replicate. ``processes``: how many processes run the replicates (the same results)."""
    if coll is None:
        return
    coll["restitution_sd"] = coll["restitution_interval_95"] = None
    coll["uncertainty"] = None
    early = lead_warning(em.config, em.snapshot_at_s)
    if early and early not in coll["warnings"]:
        coll["warnings"].append(early)
    noise = measured_noise(em)
    snap = em.snapshot
    if snap is None or noise is None or coll.get("restitution") is None:
        return
    if snap.t_s > coll["window_s"][0] + 1e-9:
        coll["warnings"].append(
            f"the uncertainty's snapshot (t = {snap.t_s:.3f} s) came after the contact window "
            f"opened (t = {coll['window_s'][0]:.3f} s): no interval (raise "
            f"uncertainty.lead_s)")
        return
    pair = tuple(int(p[3:]) for p in coll["pair"])
    until_s = min(max(em.t_s, em.config.loop.duration_s),
                  coll["window_s"][1] + 0.5 + 2 * coll["contact_duration_s"])
    cfg = em.config.uncertainty
    spread = restitution_spread(snap, pair, until_s, noise, cfg.run_replicates,
                                _rng(em.config, 1), tick, processes)
    sd, e = spread["restitution_sd"], coll["restitution"]
    coll["restitution_sd"] = sd
    if sd is not None:
        coll["restitution_interval_95"] = [e - Z95 * sd, e + Z95 * sd]
    coll["uncertainty"] = {
        "method": "closed-loop Monte Carlo of the contact window from a snapshot at "
                  f"t = {snap.t_s:.3f} s, sensor noise as measured at the calibration",
        "noise_force_N": [float(np.mean(n.sd_S[:3])) for n in noise],
        "replicates": spread["replicates"],
        "replicates_with_restitution": spread["replicates_with_restitution"]}
    if spread["replicates_with_restitution"] < spread["replicates"]:
        coll["warnings"].append(
            f"{spread['replicates'] - spread['replicates_with_restitution']} of "
            f"{spread['replicates']} replicates of the contact gave no restitution: the "
            f"interval covers those that did")


def forecast(config: EmulatorConfig, ideal: dict | None, processes: int = 1) -> dict | None:
    """Before the arms move: the restitution's predicted standard deviation for this
    contact and this sensing chain, ``collision_forecast`` in metrics.json (None without
    arms, a contact in the ideal run ``ideal`` (its collision metrics), or with
    ``[uncertainty] enabled`` off).

    A hil twin of the run with the sensor's noise off (and its calibration exact) runs
    to the snapshot; ``[uncertainty] forecast_replicates`` replicates of the window then
    run with the configured noise and calibration error. {"restitution_sd",
    "peak_force_N" (the ideal contact's), "noise_force_N" (σ per sample), and
    "peak_to_noise" (their ratio), "restitution_mean" and "restitution_error_mean" (the
    replicates' mean and its error against the ideal: the chain's predicted bias),
    "restitution_sd_se" (the forecast's own sampling error, :func:`sd_standard_error`: its
    draws are the configuration's, the same for every seed, so this error is not averaged
    out over seeds), "restitution_noise_free" (the twin's own restitution, its contact
    window run on without noise) and "restitution_systematic" (that against the ideal
    restitution: the chain's systematic error on this contact, :func:`add_systematic`),
    "rendering_error_m" and "contact_depth_m" (the twin's Eq. R1, app/runs/rendering.py:
    whether the arms will render the contact at all),
    "velocity_sd_mps" (per satellite of the pair, the replicates' per-axis standard
    deviation of its velocity after the contact, R: the pre-flight's drift check,
    app.runs.preflight.check_drift)}. ``processes``: how many processes run the
    replicates (the same results).
    """
    at_s = snapshot_time_s(config, ideal)
    if at_s is None or not config.robots or ideal.get("restitution") is None:
        return None
    quiet = merge_overrides(config, {"sensor": {"noise_force_N": 0.0, "noise_torque_Nm": 0.0},
                                     "loop": {"telemetry_capacity": 100}})
    sigma = config.sensor.noise_force_N
    out = {"restitution_sd": None, "restitution_sd_se": None, "restitution_mean": None,
           "restitution_error_mean": None, "restitution_noise_free": None,
           "restitution_systematic": None, "velocity_sd_mps": None,
           "rendering_error_m": None, "contact_depth_m": None,
           "peak_force_N": float(ideal["peak_force_N"]), "noise_force_N": sigma,
           "peak_to_noise": float(ideal["peak_force_N"]) / sigma if sigma > 0 else None,
           "replicates": config.uncertainty.forecast_count}
    twin = Emulator(quiet, mode="hil")
    try:
        twin.prepare()
    except StartPoseError as err:  # the run itself will say so, and stop there
        out["note"] = f"the noise-free twin could not start: {err}"
        return out
    early = lead_warning(config, at_s)
    if early:
        out["note"] = early
    noise = configured_noise(config)
    expect_measured_noise(twin, noise)
    while twin.status == "running" and twin.t_s < at_s - 1e-9:
        twin.step()
    if twin.status != "running":
        out["note"] = (f"the noise-free twin stopped before the contact ({twin.status}: "
                       f"{(twin.safety_stop or {}).get('reason')})")
        return out
    pair = tuple(int(p[3:]) for p in ideal["pair"])
    until_s = ideal["window_s"][1] + 0.5 + 2 * ideal["contact_duration_s"]
    snap = twin.copy_state()
    quiet_coll = replicate(snap, pair, min(until_s, config.loop.duration_s), rendering=True)
    if quiet_coll is not None:  # whether the arms will render the contact (Eq. R1)
        out["rendering_error_m"] = quiet_coll["rendering_error_m"]
        out["contact_depth_m"] = quiet_coll["contact_depth_m"]
    if quiet_coll is not None and quiet_coll["restitution"] is not None:
        out["restitution_noise_free"] = float(quiet_coll["restitution"])
        out["restitution_systematic"] = (float(quiet_coll["restitution"])
                                         - float(ideal["restitution"]))
    spread = restitution_spread(snap, pair, min(until_s, config.loop.duration_s),
                                noise, config.uncertainty.forecast_count, _rng(config, 2),
                                processes=processes)
    out["restitution_sd"] = spread["restitution_sd"]
    out["velocity_sd_mps"] = spread["velocity_sd_mps"]
    out["replicates_with_restitution"] = spread["replicates_with_restitution"]
    got = [e for e in spread["restitutions"] if e is not None]
    out["restitution_sd_se"] = sd_standard_error(got)
    if got:  # the chain's own error on the configured contact, noise included
        mean = float(np.mean(got))
        out["restitution_mean"] = mean
        out["restitution_error_mean"] = (mean - ideal["restitution"]) / ideal["restitution"]
    return out


def _ideal_of(forecast_: dict) -> float | None:
    """The ideal run's restitution e_ideal a forecast was measured against: its twin's e
    minus the twin's δ, or else its replicates' mean over (1 + their mean error)."""
    free, delta = forecast_.get("restitution_noise_free"), forecast_.get("restitution_systematic")
    if free is not None and delta is not None:
        return free - delta
    mean, error = forecast_.get("restitution_mean"), forecast_.get("restitution_error_mean")
    if mean is not None and error is not None and error != -1.0:
        return mean / (1.0 + error)
    return None


def noisy_bias(forecast_: dict | None) -> float | None:
    """The chain's systematic error on this contact with the noise in, δ_noisy =
    ē − e_ideal: the forecast's noisy replicates' mean restitution against the ideal run.
    None without a forecast, without a mean or without the ideal's e, and None where it is
    within two standard errors of that mean (sd/√n over its n replicates) of zero: a bias
    the replicates cannot tell from their own sampling error would only widen every
    interval by chance."""
    if not forecast_ or forecast_.get("restitution_mean") is None:
        return None
    ideal = _ideal_of(forecast_)
    if ideal is None:
        return None
    bias = float(forecast_["restitution_mean"]) - ideal
    sd = forecast_.get("restitution_sd")
    n = forecast_.get("replicates_with_restitution") or forecast_.get("replicates")
    if sd is not None and n and abs(bias) <= 2.0 * float(sd) / math.sqrt(n):
        return None
    return bias


def add_systematic(coll: dict | None, forecast_: dict | None) -> None:
    """Widen a run's noise interval (in ``coll``, in place) by the chain's systematic error
    on this contact, estimated two ways from the forecast: δ_twin = e_twin − e_ideal
    (``restitution_systematic``: its noise-free twin against the ideal run) and
    δ_noisy = ē − e_ideal (:func:`noisy_bias`: its noisy replicates' mean against the
    ideal). The interval reaches the larger of the two further on the side where the
    ideal lies,

        [e − 1.96 sd − max(δ_twin, δ_noisy, 0),  e + 1.96 sd + max(−δ_twin, −δ_noisy, 0)],

    so that with the noise at zero (sd 0, e = e_twin) it still holds e_ideal, and that a
    bias the noise itself creates (a contact the noise makes stick, which the twin does
    not see) is in it too. The run's e is not corrected: the twin's δ is measured without
    the state a noisy approach leaves at the contact's start, and the noisy mean is the
    forecast's own draws. ``coll["restitution_systematic"]``: δ_twin,
    ``coll["restitution_bias_noisy"]``: δ_noisy (each None without a forecast or without
    its estimate; with neither the interval is the noise's alone, and
    ``coll["uncertainty"]`` says so)."""
    if coll is None:
        return
    delta = None if not forecast_ else forecast_.get("restitution_systematic")
    noisy = noisy_bias(forecast_)
    coll["restitution_systematic"] = delta
    coll["restitution_bias_noisy"] = noisy
    interval = coll.get("restitution_interval_95")
    if interval is None:
        return
    estimates = [(d, name) for d, name in ((delta, "noise-free twin"),
                                           (noisy, "noisy replicates' mean")) if d is not None]
    if not estimates:
        if coll.get("uncertainty") is not None:
            coll["uncertainty"]["systematic"] = (
                "not included (no forecast)" if not forecast_ else
                "not included (the forecast has neither the noise-free twin's nor the "
                "noisy replicates' restitution)")
        return
    low, high = widening(estimates)
    coll["restitution_interval_95"] = [interval[0] - (0.0 if low is None else low[0]),
                                       interval[1] + (0.0 if high is None else -high[0])]
    if coll.get("uncertainty") is not None:
        coll["uncertainty"]["systematic"] = systematic_text(delta, noisy)


def widening(estimates: list[tuple[float, str]]
             ) -> tuple[tuple[float, str] | None, tuple[float, str] | None]:
    """Of the chain's systematic-error estimates ``(δ, name)``, the one that widens the
    interval's low side (the largest δ, if > 0: the ideal lies below) and the one that
    widens its high side (the smallest δ, if < 0); None where none does. A tie goes to
    the first estimate (:func:`add_systematic` lists the noise-free twin first)."""
    if not estimates:
        return None, None
    high = max(estimates, key=itemgetter(0))
    low = min(estimates, key=itemgetter(0))
    return (high if high[0] > 0 else None), (low if low[0] < 0 else None)


def systematic_text(delta: float | None, noisy: float | None) -> str:
    """How the systematic part of the interval was found, in words (δ_twin ``delta`` and
    δ_noisy ``noisy``, either None where the forecast has no such estimate)."""
    twin, mean = "the forecast's noise-free twin", "the forecast's noisy replicates' mean"
    if delta is not None and noisy is not None:
        return (f"{twin} and its noisy replicates' mean against the ideal run, the further "
                "of the two added on the ideal's side")
    return f"{twin if noisy is None else mean} against the ideal run, added on the ideal's side"


def run_interval(em: Emulator, tick=None) -> dict | None:
    """After a run that kept a snapshot (the web app's loop, which has no ideal run of its
    own): its first collision's restitution and the interval around it, {"restitution",
    "restitution_sd", "restitution_interval_95", "uncertainty"}; None without a snapshot
    or a collision."""
    from app.runs.metrics import contact_pair

    if em.snapshot is None or em.n_sat < 2:
        return None
    rows, index = em.telemetry.rows(), em.telemetry.index
    pair = contact_pair(rows, index, em.n_sat) if len(rows) else None
    if pair is None:
        return None
    bodies = {arm.satellite + 1: f"rob{arm.index + 1}" for arm in em.arms}
    coll = collision_metrics(rows, index, em.dt_s, *pair, bodies=bodies)
    if coll is None:
        return None
    spread_of_run(em, coll, tick)
    return {key: coll.get(key) for key in ("pair", "restitution", "restitution_sd",
                                           "restitution_interval_95", "uncertainty")}
