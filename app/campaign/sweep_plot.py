"""``orbit-emulator sweep-plot``: a metric of a sweep's results.csv over one setting (a line
plot, mean ± spread over the runs at each value, a line per combination of the other
settings swept) or two (a heat map of the mean)."""

from __future__ import annotations

import math
import re
from collections import defaultdict
from pathlib import Path

import numpy as np

from app.campaign.sweep import (
    FIXED_COLUMNS_HEAD,
    FIXED_COLUMNS_MID,
    FIXED_COLUMNS_TAIL,
    read_results,
)

UNITS = {
    "Npm": "N/m", "spm": "s/m", "mps": "m/s", "mps2": "m/s²", "radps": "rad/s",
    "radps2": "rad/s²", "rad": "rad", "deg": "°", "s": "s", "ms": "ms", "us": "µs", "m": "m",
    "mm": "mm", "N": "N", "Nm": "N·m", "Ns": "N·s", "J": "J", "kg": "kg", "kgm2": "kg·m²",
    "hz": "Hz", "Hz": "Hz", "cycles": "cycles", "MiB": "MiB",
}
"""A name's last ``_part`` → its unit (the project names every quantity with its unit)."""

MAX_LINES = 8
"""More combinations of the other settings than this: one line, the mean over them all."""


def unit_of(name: str) -> str | None:
    """The unit of a setting or metric from its dotted name: the unit suffix of the last
    part that has one (``satellites.0.velocity_mps.0`` → m/s, ``cycle_time_us.p50`` →
    µs); None for a pure number (``collision.restitution``)."""
    for part in reversed(name.split(".")):
        if part.isdigit():
            continue
        suffix = part.rpartition("_")[2] if "_" in part else None
        if suffix in UNITS:
            return UNITS[suffix]
    return None


def label(name: str) -> str:
    unit = unit_of(name)
    return f"{name} ({unit})" if unit else name


def _number(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def plot_sweep(sweep_dir: Path, x: str, y: str | None, metric: str,
               out: str | Path | None = None) -> Path:
    """Write the plot; its path. Raises ValueError naming what is missing."""
    table = sweep_dir / "results.csv"
    if not table.is_file():
        raise ValueError(f"{sweep_dir}: no results.csv (the output directory of "
                         f"`orbit-emulator sweep`)")
    columns, rows = read_results(table)
    fixed = (*FIXED_COLUMNS_HEAD, *FIXED_COLUMNS_MID, *FIXED_COLUMNS_TAIL)
    start, end = columns.index("seed") + 1, columns.index("status")
    settings = columns[start:end]
    metrics = columns[columns.index("reason") + 1:columns.index("wall_s")]
    for flag, key in (("--x", x), ("--y", y)):
        if key is not None and key not in settings:
            raise ValueError(f"{flag}: {key!r} is not a setting the sweep varied (its "
                             f"settings: {', '.join(settings) or 'none'})")
    if x == y:
        raise ValueError("--y: the same setting as --x")
    if metric not in metrics and metric not in fixed:
        raise ValueError(f"--metric: {metric!r} is not a column of {table} (its metrics: "
                         f"{', '.join(metrics)})")
    points = []
    for r in rows:
        value, xv = _number(r[metric]), _number(r[x])
        yv = _number(r[y]) if y else 0.0
        if value is not None and xv is not None and yv is not None:
            points.append((r, xv, yv, value))
    if not points:
        raise ValueError(f"--metric: no run in {table} has a number for {metric!r} "
                         f"{'and' if y else 'at'} a numeric {x!r}"
                         + (f" and {y!r}" if y else ""))
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", f"{metric}_vs_{x}" + (f"_{y}" if y else ""))
    path = Path(out) if out else sweep_dir / f"{name}.png"
    if path.suffix.lower() != ".png":
        path = path.with_name(path.name + ".png")  # (a PNG, whatever the name said)
    for parent in path.parents:
        if parent.exists() and not parent.is_dir():
            raise ValueError(f"--out: {parent} is a file, not a directory")
    if path.is_dir():
        raise ValueError(f"--out: {path} is a directory; name the PNG file")
    others = [k for k in settings if k not in (x, y)]
    if y:
        _heat_map(points, x, y, metric, path)
    else:
        _line_plot(points, x, metric, others, path)
    return path


def _line_plot(points, x: str, metric: str, others: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[tuple, dict[float, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r, xv, _, value in points:
        groups[tuple(r[k] for k in others)][xv].append(value)
    if len(groups) > MAX_LINES:
        merged: dict[float, list[float]] = defaultdict(list)
        for g in groups.values():
            for xv, vals in g.items():
                merged[xv] += vals
        groups, note = {(): merged}, f", mean over {', '.join(others)}"
    else:
        note = ""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for key, by_x in groups.items():
        xs = sorted(by_x)
        mean = np.array([np.mean(by_x[v]) for v in xs])
        lo = np.array([np.min(by_x[v]) for v in xs])
        hi = np.array([np.max(by_x[v]) for v in xs])
        # (merged over more than MAX_LINES combinations, the one line's key is empty)
        text = ", ".join(f"{k} = {v}" for k, v in zip(others, key, strict=True)) \
            if key else "mean"
        line, = ax.plot(xs, mean, marker="o", label=text)
        if np.any(hi > lo):
            ax.fill_between(xs, lo, hi, color=line.get_color(), alpha=0.2)
    n = max(len(v) for g in groups.values() for v in g.values())
    ax.set_xlabel(label(x))
    ax.set_ylabel(label(metric))
    ax.set_title(f"{metric}: mean, band min–max over the runs at each value (up to {n})"
                 f"{note}", fontsize=9)
    ax.grid(alpha=0.3)
    if len(groups) > 1 or others:
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _heat_map(points, x: str, y: str, metric: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xs = sorted({p[1] for p in points})
    ys = sorted({p[2] for p in points})
    cells: dict[tuple[float, float], list[float]] = defaultdict(list)
    for _, xv, yv, value in points:
        cells[(xv, yv)].append(value)
    grid = np.full((len(ys), len(xs)), np.nan)
    for (xv, yv), vals in cells.items():
        grid[ys.index(yv), xs.index(xv)] = np.mean(vals)
    fig, ax = plt.subplots(figsize=(1.2 * len(xs) + 3.5, 0.8 * len(ys) + 2.5))
    image = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
    for (xv, yv), vals in cells.items():
        ax.text(xs.index(xv), ys.index(yv), f"{np.mean(vals):.3g}", ha="center",
                va="center", fontsize=8, color="white")
    ax.set_xticks(range(len(xs)), [f"{v:g}" for v in xs])
    ax.set_yticks(range(len(ys)), [f"{v:g}" for v in ys])
    ax.set_xlabel(label(x))
    ax.set_ylabel(label(y))
    n = max(len(v) for v in cells.values())
    ax.set_title(f"{metric}: mean over the runs in each cell (up to {n})", fontsize=9)
    fig.colorbar(image, ax=ax, label=label(metric))
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
