"""Writing what a run recorded: telemetry CSV and metrics JSON."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np


def write_telemetry_csv(path: str | Path, columns: list[str], rows: np.ndarray) -> None:
    """CSV with a header line; floats in %.12g so equal runs give equal bytes."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(telemetry_csv_text(columns, rows))


def telemetry_csv_text(columns: list[str], rows: np.ndarray) -> str:
    """The telemetry CSV as a string (what :func:`write_telemetry_csv` writes)."""
    buf = io.StringIO()
    buf.write(",".join(columns) + "\n")
    if len(rows):
        np.savetxt(buf, rows, delimiter=",", fmt="%.12g")
    return buf.getvalue()


def write_json(path: str | Path, data: dict) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n")
