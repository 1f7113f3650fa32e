"""Telemetry: column names, a bounded ring buffer of per-cycle rows, and the recorder.

The loop appends one row of floats per cycle, written in place by compiled kernels;
readers take copies (snapshots), so they never hold the loop up. When the buffer is full
the oldest rows are overwritten and counted in ``dropped`` (a headless run sizes the
buffer to hold the whole run).

Row layout: ``t_s``; per satellite its ODS state and the wrench the ODS received
(:data:`SAT_FIELDS`); per arm its actual mockup and joints and the raw F/T reading
(:data:`ROBOT_FIELDS`); per satellite the true external force on the actual mockup; per
satellite the wrench of its own GNC (:data:`GNC_FIELDS`; zeros without one).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit
from numba.core.errors import TypingError

from app.sim.frames import matrix_to_quat_into
from app.sim.orbital import omega_relative_into

SAT_FIELDS = (
    "x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps",
    "qw", "qx", "qy", "qz", "wx_radps", "wy_radps", "wz_radps",
    "fx_N", "fy_N", "fz_N", "tx_Nm", "ty_Nm", "tz_Nm",
)
ROBOT_FIELDS = (
    "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz", "vx_mps", "vy_mps", "vz_mps",
    *(f"q{j}_rad" for j in range(1, 7)),
    "ft_fx_N", "ft_fy_N", "ft_fz_N", "ft_tx_Nm", "ft_ty_Nm", "ft_tz_Nm",
    "pft_fx_N", "pft_fy_N", "pft_fz_N", "pft_tx_Nm", "pft_ty_Nm", "pft_tz_Nm",
)
GNC_FIELDS = ("gnc_fx_N", "gnc_fy_N", "gnc_fz_N", "gnc_tx_Nm", "gnc_ty_Nm", "gnc_tz_Nm")


def satellite_columns(count: int) -> list[str]:
    """Columns of the ODS state of `count` satellites (1-based ``sat{i}_...``)."""
    return [f"sat{i}_{f}" for i in range(1, count + 1) for f in SAT_FIELDS]


def robot_columns(count: int) -> list[str]:
    """Columns of `count` arms: actual mockup pose and velocity in R, joints, raw F/T (in
    the sensor frame) and processed F/T (the wrench on the COM the chain hands the
    coupling: force in R, torque in body axes)."""
    return [f"rob{i}_{f}" for i in range(1, count + 1) for f in ROBOT_FIELDS]


def true_force_columns(count: int) -> list[str]:
    """Columns of the true external force on each actual mockup (in R)."""
    return [f"sat{i}_true_f{a}_N" for i in range(1, count + 1) for a in "xyz"]


def gnc_columns(count: int) -> list[str]:
    """Columns of each satellite's own GNC wrench (app/sim/gnc.py), in ORBIT units: the
    thrusters' force in R and the wheels' torque in body axes."""
    return [f"sat{i}_{f}" for i in range(1, count + 1) for f in GNC_FIELDS]


RAIL_FIELDS = ("rail_s_m", "rail_v_mps", "rail_sp_m")


def rail_columns(robots: Sequence[int]) -> list[str]:
    """Columns of the robots (1-based numbers) that stand on a rail: the carriage's position
    and speed along its axis and the set-point the VFDM sent it (app/sim/rail_servo.py)."""
    return [f"rob{i}_{f}" for i in robots for f in RAIL_FIELDS]


def loop_columns(n_sat: int, n_arms: int, rail_robots: Sequence[int] = ()) -> list[str]:
    """Every column of the loop's telemetry, in row order (the rails' last, only for the
    robots that have one)."""
    return ["t_s", *satellite_columns(n_sat), *robot_columns(n_arms),
            *true_force_columns(n_sat), *gnc_columns(n_sat), *rail_columns(rail_robots)]


class TelemetryBuffer:
    """Fixed-capacity ring buffer of float rows with named columns.

    Its state is two counters: rows claimed and rows committed (completely written), both
    since the start. Storage and counters may be given (e.g. arrays in shared memory), so
    that another process can read the rows while they are written: :func:`ring_rows`.
    """

    def __init__(self, columns: list[str], capacity: int, data: np.ndarray | None = None,
                 counters: np.ndarray | None = None) -> None:
        if capacity < 1:
            raise ValueError("capacity must be at least 1")
        self.columns = list(columns)
        self.index = {name: k for k, name in enumerate(self.columns)}
        if data is None:
            data = np.zeros((capacity, len(self.columns)))
        if data.shape != (capacity, len(self.columns)):
            raise ValueError(f"storage of shape {data.shape} for {capacity} rows of "
                             f"{len(self.columns)} columns")
        self._data = data
        self._counters = np.zeros(2, dtype=np.int64) if counters is None else counters
        self._counters[:] = 0

    @property
    def capacity(self) -> int:
        return self._data.shape[0]

    @property
    def count(self) -> int:
        """Rows held (at most the capacity)."""
        return min(int(self._counters[0]), self.capacity)

    @property
    def dropped(self) -> int:
        """Rows overwritten by newer ones."""
        return max(0, int(self._counters[0]) - self.capacity)

    def append(self, row: np.ndarray) -> None:
        """Store one row (length = number of columns)."""
        self.next_row()[:] = row
        self.commit()

    def next_row(self) -> np.ndarray:
        """Claim the next row and return it (a view) for the caller to fill in place.

        It counts as appended at once (and, when full, overwrites the oldest row); a
        reader in another process sees it only after :meth:`commit`.
        """
        claimed = int(self._counters[0])
        self._counters[0] = claimed + 1
        return self._data[claimed % self.capacity]

    def commit(self) -> None:
        """Every claimed row is completely written."""
        self._counters[1] = self._counters[0]

    def rows(self, last: int | None = None) -> np.ndarray:
        """A copy of the stored rows, oldest first (the newest `last` only, if given)."""
        n = self.count if last is None else min(last, self.count)
        start = (int(self._counters[0]) - n) % self.capacity
        idx = (start + np.arange(n)) % self.capacity
        return self._data[idx].copy()

    def column(self, name: str, last: int | None = None) -> np.ndarray:
        return self.rows(last)[:, self.index[name]]

    def clear(self) -> None:
        self._counters[:] = 0

    def use_storage(self, data: np.ndarray, counters: np.ndarray) -> None:
        """Keep the rows from now on in ``data`` (capacity, columns) with the two counters
        in ``counters`` (int64 (2,)); only while empty."""
        if self._counters[0]:
            raise ValueError("the buffer already holds rows")
        if data.shape != self._data.shape or counters.shape != (2,):
            raise ValueError(f"storage of shape {data.shape} and counters {counters.shape} "
                             f"for a buffer of shape {self._data.shape}")
        self._data, self._counters = data, counters
        self._counters[:] = 0


def ring_rows(data: np.ndarray, counters: np.ndarray) -> np.ndarray:
    """The committed rows of a ring written elsewhere meanwhile (oldest first, a copy).

    Rows committed before the copy began are whole; a row whose slot the writer claimed
    again while the copy ran may be torn, so the rows kept are those numbered
    ``[claimed_after − capacity, committed_before)``.
    """
    return numbered_ring_rows(data, counters)[1]


def numbered_ring_rows(data: np.ndarray, counters: np.ndarray) -> tuple[int, np.ndarray]:
    """(the number of the first row since the run began, the rows): see ring_rows."""
    capacity = data.shape[0]
    committed = int(counters[1])
    start = max(0, committed - capacity)
    rows = data[np.arange(start, committed) % capacity]  # a copy of those rows only
    claimed = int(counters[0])
    first = max(start, claimed - capacity)
    if first >= committed:
        return committed, np.empty((0, data.shape[1]))
    return first, rows[first - start:]


# --- row kernels ----------------------------------------------------------------------------


@njit(cache=True, fastmath=False)
def record_satellites(t_s, y, orbit_rate, force_R, torque_B, row):
    """row[0] = t and the ODS columns of every satellite; returns the next free index.

    Per satellite: position, velocity, attitude (wxyz), angular velocity relative to R
    (body axes), applied force and torque (:data:`SAT_FIELDS`).
    """
    row[0] = t_s
    k = 1
    for i in range(y.shape[0]):
        for c in range(10):
            row[k + c] = y[i, c]
        omega_relative_into(y, i, orbit_rate, row, k + 10)
        for a in range(3):
            row[k + 13 + a] = force_R[i, a]
            row[k + 16 + a] = torque_B[i, a]
        k += 19
    return k


@njit(cache=True, fastmath=False)
def record_arm(T_R_W, T_W_C, v_W, q, raw_S, processed, row, k):
    """An arm's columns from row[k] (:data:`ROBOT_FIELDS`); returns the next free index.

    Mockup COM position and attitude (wxyz) in R, from ``T_R_W · T_W_C``; its velocity
    in R; the joint positions; the raw F/T reading; the processed wrench.
    """
    R = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            R[a, b] = (T_R_W[a, 0] * T_W_C[0, b] + T_R_W[a, 1] * T_W_C[1, b]
                       + T_R_W[a, 2] * T_W_C[2, b])
    for a in range(3):
        row[k + a] = (T_R_W[a, 0] * T_W_C[0, 3] + T_R_W[a, 1] * T_W_C[1, 3]
                      + T_R_W[a, 2] * T_W_C[2, 3] + T_R_W[a, 3])
        row[k + 7 + a] = T_R_W[a, 0] * v_W[0] + T_R_W[a, 1] * v_W[1] + T_R_W[a, 2] * v_W[2]
    matrix_to_quat_into(R, row, k + 3)
    for j in range(6):
        row[k + 10 + j] = q[j]
        row[k + 16 + j] = raw_S[j]
        row[k + 22 + j] = processed[j]
    return k + 28


@njit(cache=True, fastmath=False)
def record_row(t_s, y, orbit_rate, force_R, torque_B, true_force_R, gnc, rails, n_arms,
               data, counters):
    """Claim the next row of the ring (data, counters: :class:`TelemetryBuffer`'s) and
    write every column but the arms' (:func:`record_satellites`, then the true forces,
    the GNC wrenches and the rails after the ``n_arms`` arms' columns); returns the row's
    index in data, or -1 (nothing claimed, nothing written) if a shape does not fit the
    row: y (N, 13), force_R, torque_B, true_force_R (N, 3), gnc (N, 6), rails (n, 3)."""
    n = y.shape[0]
    width = 1 + (len(SAT_FIELDS) + 9) * n + len(ROBOT_FIELDS) * n_arms + 3 * rails.shape[0]
    if (y.shape[1] != 13 or force_R.shape[0] != n or force_R.shape[1] != 3
            or torque_B.shape[0] != n or torque_B.shape[1] != 3
            or true_force_R.shape[0] != n or true_force_R.shape[1] != 3
            or gnc.shape[0] != n or gnc.shape[1] != 6 or rails.shape[1] != 3
            or width != data.shape[1]):
        return -1
    claimed = counters[0]
    counters[0] = claimed + 1
    at = claimed % data.shape[0]
    row = data[at]
    k = record_satellites(t_s, y, orbit_rate, force_R, torque_B, row)
    k += len(ROBOT_FIELDS) * n_arms
    for i in range(n):
        for a in range(3):
            row[k + 3 * i + a] = true_force_R[i, a]
        for c in range(6):
            row[k + 3 * n + 6 * i + c] = gnc[i, c]
    k += 9 * n
    for r in range(rails.shape[0]):
        for c in range(3):
            row[k + 3 * r + c] = rails[r, c]
    return at


@njit(cache=True, fastmath=False)
def record_row_arm(t_s, y, orbit_rate, force_R, torque_B, true_force_R, gnc, rails, n_arms,
                   data, counters, T_R_W, T_W_C, v_W, q, raw_S, processed):
    """:func:`record_row`, then the first arm's columns (:func:`record_arm`) in the same
    call (a loop with arms: one call fewer); -1 as record_row."""
    at = record_row(t_s, y, orbit_rate, force_R, torque_B, true_force_R, gnc, rails, n_arms,
                    data, counters)
    if at >= 0:
        record_arm(T_R_W, T_W_C, v_W, q, raw_S, processed, data[at],
                   1 + len(SAT_FIELDS) * y.shape[0])
    return at


@njit(cache=True, fastmath=False)
def record_row_arms(t_s, y, orbit_rate, force_R, torque_B, true_force_R, gnc, rails, n_arms,
                    data, counters, T_R_W, T_W_C, v_W, q, raw_S, processed, T_W_C2, v_W2, q2,
                    raw_S2, processed2):
    """:func:`record_row_arm`, then the second arm's columns (:func:`record_arm`) in the
    same call (a dual-arm loop: one call per row); -1 as record_row."""
    at = record_row_arm(t_s, y, orbit_rate, force_R, torque_B, true_force_R, gnc, rails,
                        n_arms, data, counters, T_R_W, T_W_C, v_W, q, raw_S, processed)
    if at >= 0:
        record_arm(T_R_W, T_W_C2, v_W2, q2, raw_S2, processed2, data[at],
                   1 + len(SAT_FIELDS) * y.shape[0] + len(ROBOT_FIELDS))
    return at


class Recorder:
    """Writes the loop's telemetry row of each cycle into a :class:`TelemetryBuffer`."""

    def __init__(self, n_sat: int, n_arms: int, capacity: int, T_R_W: np.ndarray,
                 orbit_rate_radps: float, rail_robots: Sequence[int] = ()) -> None:
        self.buffer = TelemetryBuffer(loop_columns(n_sat, n_arms, rail_robots), capacity)
        self.n_sat, self.n_arms = n_sat, n_arms
        self.n_rails = len(rail_robots)
        self.T_R_W = np.ascontiguousarray(T_R_W, dtype=float)
        self.orbit_rate_radps = float(orbit_rate_radps)
        self._no_gnc = np.zeros((n_sat, 6))  # the GNC columns without a GNC
        self._no_rails = np.zeros((0, 3))
        self._arms_at = 1 + len(SAT_FIELDS) * n_sat  # the first arm's column

    def record(self, t_s: float, y: np.ndarray, force_R: np.ndarray, torque_B: np.ndarray,
               arms, true_force_R: np.ndarray, gnc_wrench: np.ndarray | None = None,
               rails: np.ndarray | None = None) -> None:
        """One row: time, ODS state y (N, 13) with the wrench (N, 3) + (N, 3) it receives,
        each arm's ``(T_W_C, v_W, q_rad, raw_S, processed)``, the true force on each
        mockup (N, 3), each satellite's GNC wrench (N, 6: force in R, torque in body
        axes, orbit units; None: zeros) and each rail's (s, v, set-point) (n_rails, 3).

        The kernels write without bounds checks: the shapes are checked first (the row's
        kernel checks them before it claims the row), so that a wrong call raises and
        records nothing."""
        bad = len(arms) != self.n_arms or (rails is None) == bool(self.n_rails)
        if not bad:
            buffer = self.buffer
            common = (t_s, y, self.orbit_rate_radps, force_R, torque_B, true_force_R,
                      self._no_gnc if gnc_wrench is None else gnc_wrench,
                      self._no_rails if rails is None else rails, self.n_arms,
                      buffer._data, buffer._counters)
            try:  # claims the row only if every shape fits (-1 if not)
                at = (record_row(*common) if not arms
                      else record_row_arm(*common, self.T_R_W, *arms[0]) if len(arms) == 1
                      else record_row_arms(*common, self.T_R_W, *arms[0], *arms[1]))
            except TypingError:  # an array of another dimension or type
                at = -1
            bad = at < 0
        if bad:
            n = self.n_sat
            raise ValueError(
                f"recorder of {n} satellites and {self.n_arms} arms got a state {y.shape}, "
                f"wrenches {np.shape(force_R)} {np.shape(torque_B)} {np.shape(true_force_R)}"
                f"{'' if gnc_wrench is None else f' {np.shape(gnc_wrench)}'}, "
                f"{len(arms)} arms"
                f"{'' if rails is None else f', rails {np.shape(rails)}'}"
                f"{f' (it has {self.n_rails} rails)' if self.n_rails else ''}"
            )
        if len(arms) > 2:  # the first two arms' columns are written
            row, k = buffer._data[at], self._arms_at + 2 * len(ROBOT_FIELDS)
            for T_W_C, v_W, q_rad, raw_S, processed in arms[2:]:
                k = record_arm(self.T_R_W, T_W_C, v_W, q_rad, raw_S, processed, row, k)
        buffer.commit()
