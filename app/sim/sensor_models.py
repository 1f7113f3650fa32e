"""F/T sensors a lab can choose (``[sensor] model``), each with its data sheet's figures.

A model sets the sensor's range, noise, sample rate and delay; any of them given in
``[sensor]`` overrides the model's (app/config/ SensorConfig). The chain downstream (the
lab's processing, the contact gate, the lag compensation) reads the resolved values.

How the figures are read:

* *range*: one bound for the three force axes and one for the three torques (the model
  clips each component at it); where the data sheet gives a larger F_z than F_xy, the
  smaller F_xy, so that no axis reads beyond its rating.
* *noise*: the standard deviation of one sample. A data sheet's "resolution" (ATI: the
  smallest change the system resolves, its noise-free counts) is taken as one standard
  deviation; a "precision" given as a ± band (UR) as three; a "signal noise" (Robotiq) as
  one.
* *sample rate*: new readings per second. Below the loop's rate a reading is held
  between samples (zero-order hold, app/sim/ft_sensor.py VirtualFTSensor).
* *delay*: whole loop cycles at the lab's 500 Hz between the instant a reading is taken
  and the cycle that uses it: the data sheet's latency (transport included) rounded to
  the nearest 2 ms cycle. At another loop rate, set ``[sensor] delay_cycles`` by hand.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SENSOR_MODELS", "SensorModel", "hold_lag_cycles", "sample_every_cycles"]


@dataclass(frozen=True)
class SensorModel:
    """The data-sheet figures of one F/T sensor (see the module doc for how each is read)."""

    range_force_N: float
    range_torque_Nm: float
    noise_force_N: float
    noise_torque_Nm: float
    sample_rate_hz: float | None
    """None: a new reading every loop cycle (at least the loop's rate)."""
    delay_cycles: int
    source: str


SENSOR_MODELS: dict[str, SensorModel] = {
    # Universal Robots, UR10e technical specifications (e-Series, 2019): force/torque
    # sensor range 100 N / 10 N·m, precision ±5.0 N / ±0.2 N·m (read as 3 sigma: 1.67 N,
    # 0.067 N·m), read by the controller at its 500 Hz; the delay of one cycle is this
    # project's assumption (DESIGN.md "The simulated UR10e"), the data sheet gives none.
    "ur10e": SensorModel(100.0, 10.0, 5.0 / 3.0, 0.2 / 3.0, None, 1,
                         "UR10e technical specifications (e-Series)"),
    # ATI Industrial Automation, Gamma SI-130-10 calibration (F/T sensor catalogue, Gamma
    # page): F_xy 130 N (F_z 400 N), T_xyz 10 N·m; resolution with Net F/T 1/40 N and
    # 1/800 N·m (one sigma: 0.025 N, 0.00125 N·m). Net F/T: RDT streaming up to 7000 Hz
    # (above any loop here), latency from the event to the Ethernet output 288 µs (ATI,
    # "F/T system interfaces": Net F/T) — well under a 2 ms cycle: the reading the loop
    # takes is this cycle's (delay 0). Checked against a copy: the Net F/T rate and latency
    # (ati-ia.com, F/T system interfaces); the calibration's range and resolution are
    # ATI's published SI-130-10 figures as quoted, to check against the current sheet.
    "ati-gamma": SensorModel(130.0, 10.0, 1.0 / 40.0, 1.0 / 800.0, None, 0,
                             "ATI Gamma SI-130-10 with Net F/T"),
    # ATI Mini45 SI-145-5 calibration (F/T sensor catalogue, Mini45 page): F_xy 145 N
    # (F_z 290 N), T_xyz 5 N·m; resolution with Net F/T 1/16 N and 1/752 N·m (one sigma).
    # Same Net F/T interface as the Gamma: 7000 Hz, 288 µs (delay 0). The range and
    # resolution are ATI's published SI-145-5 figures as recalled, not checked against a
    # copy of the sheet here: check them before relying on the Mini45's row.
    "ati-mini45": SensorModel(145.0, 5.0, 1.0 / 16.0, 1.0 / 752.0, None, 0,
                              "ATI Mini45 SI-145-5 with Net F/T"),
    # Robotiq FT 300-S Force Torque Sensor, instruction manual (specifications and section
    # 4.4 "Serial communication"): range ±300 N / ±30 N·m, signal noise 0.1 N and
    # 0.005 N·m (one sigma), data stream of 16-byte frames at 100 Hz over RS-485 at
    # 19200 bps: a frame takes 16 x 10 bits / 19200 bps = 8.3 ms on the wire after it was
    # sampled, 4 cycles at 500 Hz. Checked against a copy: the 100 Hz stream and the 19200
    # bps link (manual, section 4.4); the range and noise as quoted from the data sheet.
    "robotiq-ft300s": SensorModel(300.0, 30.0, 0.1, 0.005, 100.0, 4,
                                  "Robotiq FT 300-S instruction manual"),
}
"""The sensor models by their ``[sensor] model`` name."""


def sample_every_cycles(sample_rate_hz: float | None, rate_hz: float) -> float:
    """Loop cycles per new reading: 1 when the sensor samples at least as fast as the loop."""
    if sample_rate_hz is None or sample_rate_hz >= rate_hz:
        return 1.0
    return rate_hz / sample_rate_hz


def hold_lag_cycles(sample_rate_hz: float | None, rate_hz: float) -> float:
    """How far (cycles) the zero-order hold of a slower sensor lags a ramp, on average: a
    reading is held for N = rate / sample rate cycles, so it is (N − 1)/2 cycles old on
    average (0 when the sensor samples every cycle)."""
    return 0.5 * (sample_every_cycles(sample_rate_hz, rate_hz) - 1.0)
