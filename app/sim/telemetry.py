"""Telemetry: column names and a bounded ring buffer of per-cycle rows.

The loop appends one row of floats per cycle; readers take copies (snapshots), so they
never hold the loop up. When the buffer is full the oldest rows are overwritten and
counted in ``dropped`` (a headless run sizes the buffer to hold the whole run).
"""

from __future__ import annotations

import numpy as np

SAT_FIELDS = (
    "x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps",
    "qw", "qx", "qy", "qz", "wx_radps", "wy_radps", "wz_radps",
    "fx_N", "fy_N", "fz_N", "tx_Nm", "ty_Nm", "tz_Nm",
)
ROBOT_FIELDS = (
    "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz", "vx_mps", "vy_mps", "vz_mps",
    *(f"q{j}_rad" for j in range(1, 7)),
    "ft_fx_N", "ft_fy_N", "ft_fz_N", "ft_tx_Nm", "ft_ty_Nm", "ft_tz_Nm",
)


def satellite_columns(count: int) -> list[str]:
    """Columns of the ODS state of `count` satellites (1-based ``sat{i}_...``)."""
    return [f"sat{i}_{f}" for i in range(1, count + 1) for f in SAT_FIELDS]


def robot_columns(count: int) -> list[str]:
    """Columns of `count` arms: actual mockup pose and velocity in R, joints, raw F/T."""
    return [f"rob{i}_{f}" for i in range(1, count + 1) for f in ROBOT_FIELDS]


class TelemetryBuffer:
    """Fixed-capacity ring buffer of float rows with named columns."""

    def __init__(self, columns: list[str], capacity: int) -> None:
        if capacity < 1:
            raise ValueError("capacity must be at least 1")
        self.columns = list(columns)
        self.index = {name: k for k, name in enumerate(self.columns)}
        self._data = np.zeros((capacity, len(self.columns)))
        self._next = 0
        self.count = 0
        self.dropped = 0

    @property
    def capacity(self) -> int:
        return self._data.shape[0]

    def append(self, row: np.ndarray) -> None:
        """Store one row (length = number of columns)."""
        self.next_row()[:] = row

    def next_row(self) -> np.ndarray:
        """Claim the next row and return it (a view) for the caller to fill in place.

        It counts as appended at once (and, when full, overwrites the oldest row).
        """
        row = self._data[self._next]
        self._next = (self._next + 1) % self.capacity
        if self.count < self.capacity:
            self.count += 1
        else:
            self.dropped += 1
        return row

    def rows(self, last: int | None = None) -> np.ndarray:
        """A copy of the stored rows, oldest first (the newest `last` only, if given)."""
        n = self.count if last is None else min(last, self.count)
        start = (self._next - n) % self.capacity
        idx = (start + np.arange(n)) % self.capacity
        return self._data[idx].copy()

    def column(self, name: str, last: int | None = None) -> np.ndarray:
        return self.rows(last)[:, self.index[name]]

    def clear(self) -> None:
        self._next = 0
        self.count = 0
        self.dropped = 0
