"""Two runs kept on disk (app/runs/store.py) compared: the settings that differ, and one of
their figures with both runs on the same axes.

The overlay is planned from each run's own telemetry, configuration and metrics exactly as
its figure is (app/runs/plots.py plan_figures), then merged panel by panel (panels match
by title and axis label): run A's lines solid, run B's dashed, each line's colour naming
its quantity (its axis, and what it is: received, true, mockup ...), and each panel's
legend naming the two runs first. Limits, events and the contact's shading are run A's
(B's where A has none in that panel). A run longer than :data:`MAX_OVERLAY_ROWS` rows is
read every k-th row (the title says so): the overlay's memory is bounded whatever the
runs' length.

File I/O and drawing only; run in a worker process (matplotlib stays out of the web
process).
"""

from __future__ import annotations

import io
import json
import math
import re
from pathlib import Path

import numpy as np

from app.runs.plots import FIGURES, Figure, Line, Panel

__all__ = ["MAX_OVERLAY_ROWS", "compare_png", "figure_names", "overlay", "settings_diff"]

MAX_OVERLAY_ROWS = 50_000
"""At most this many rows of each run are read for an overlay (every k-th beyond)."""

_KIND = {"-": 0, "--": 1, ":": 2}
"""A line's style in its run's own figure: what it is (ODS / received, mockup, true)."""


class UnknownFigure(ValueError):
    """A figure name that is not one of app/runs/plots.py's (the message lists them)."""


def figure_names() -> list[str]:
    return list(FIGURES)


def check_figure(name: str) -> str:
    if name not in FIGURES:
        raise UnknownFigure(f"figure {name!r}: not a run's figure (one of "
                            f"{', '.join(FIGURES)})")
    return name


def _flatten(value, prefix: str, out: dict) -> dict:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(v, f"{prefix}.{k}" if prefix else str(k), out)
    elif isinstance(value, list) and any(isinstance(v, (dict, list)) for v in value):
        for k, v in enumerate(value):
            _flatten(v, f"{prefix}.{k}", out)
    else:
        out[prefix] = value
    return out


def settings_diff(saved_a: dict, saved_b: dict) -> list[dict]:
    """The settings that differ between two runs' config.json ({"scenario", "mode",
    "config"}): [{"key", "a", "b"}] by dotted key (list items by index; a key only one
    run has: null on the other side), sorted."""
    flat_a = _flatten({"scenario": saved_a.get("scenario"), "mode": saved_a.get("mode"),
                       **(saved_a.get("config") or {})}, "", {})
    flat_b = _flatten({"scenario": saved_b.get("scenario"), "mode": saved_b.get("mode"),
                       **(saved_b.get("config") or {})}, "", {})
    return [{"key": k, "a": flat_a.get(k), "b": flat_b.get(k)}
            for k in sorted(set(flat_a) | set(flat_b)) if flat_a.get(k) != flat_b.get(k)]


def _restyle(line: Line, tag: str, style: str) -> Line:
    base = int(line.color[1:]) if line.color and line.color[1:].isdigit() else 0
    colour = f"C{(base + 3 * _KIND.get(line.style, 0)) % 10}"
    return Line(line.t, line.y, f"{tag} {line.label}", style, colour, line.width)


STYLE_NOTE = re.compile(r" \([^()]*\b(?:solid|dashed|dotted)\b[^()]*\)$")
"""A panel title's note of its line styles ("(received solid, true dotted)"): the overlay
restyles every line (A solid, B dashed, the kind by colour), so it drops such notes."""


def overlay(fig_a: Figure | None, fig_b: Figure | None, id_a: str, id_b: str,
            note: str = "") -> Figure:
    """One figure of two runs' versions of the same figure (module doc); at least one of
    them is given."""
    some = fig_a or fig_b
    panels: dict[tuple[str, str], Panel] = {}
    for fig, tag, style in ((fig_a, "A", "-"), (fig_b, "B", "--")):
        for panel in (fig.panels if fig is not None else []):
            title = STYLE_NOTE.sub("", panel.title or "") or panel.title
            key = (title, panel.ylabel)
            lines = [_restyle(line, tag, style) for line in panel.lines]
            if key not in panels:
                legend = [Line(np.empty(0), np.empty(0), f"A {id_a}", "-", "k"),
                          Line(np.empty(0), np.empty(0), f"B {id_b}", "--", "k")]
                panels[key] = Panel(panel.ylabel, legend + lines, panel.min_span,
                                    list(panel.limits), panel.log, panel.shade,
                                    f"{panel.shade_label} ({tag})", list(panel.marks),
                                    title, panel.magnitude)
            else:
                merged = panels[key]
                merged.lines += lines
                if merged.shade is None and panel.shade is not None:
                    merged.shade, merged.shade_label = panel.shade, f"{panel.shade_label} (B)"
                merged.limits += [x for x in panel.limits if x not in merged.limits]
                merged.marks += [x for x in panel.marks if x not in merged.marks]
    missing = [f"{tag} has no such figure" for fig, tag in ((fig_a, "A"), (fig_b, "B"))
               if fig is None]
    title = (f"{FIGURES[some.name]}: A {id_a} (solid) against B {id_b} (dashed)"
             + (f"; {', '.join(missing)}" if missing else "") + (f"\n{note}" if note else ""))
    return Figure(some.name, title, list(panels.values()), xlabel=some.xlabel)


def _planned(folder: Path, name: str, max_rows: int) -> tuple[Figure | None, int]:
    """(run ``folder``'s figure ``name`` as planned from its files, or None if it has
    none; the step its rows were read at)."""
    from app.runs.plots import plan_figures
    from app.runs.store import read_telemetry_every, run_config, telemetry_span

    telemetry = folder / "telemetry.csv"
    metrics_path = folder / "metrics.json"
    metrics = json.loads(metrics_path.read_text()) if metrics_path.is_file() else {}
    _, n_rows, _, _ = telemetry_span(telemetry)
    step = max(1, math.ceil(n_rows / max_rows))
    columns, rows = read_telemetry_every(telemetry, step, n_rows)
    if not len(rows):
        return None, step
    index = {c: k for k, c in enumerate(columns)}
    figures = plan_figures(rows, index, run_config(folder), metrics or {})
    return next((f for f in figures if f.name == name), None), step


def compare_png(folder_a: str, folder_b: str, name: str,
                max_rows: int = MAX_OVERLAY_ROWS) -> bytes | None:
    """The PNG of figure ``name`` of the runs in ``folder_a`` and ``folder_b`` overlaid;
    None if neither run has that figure."""
    from app.runs.plots import draw, pyplot

    plt = pyplot()

    check_figure(name)
    (fig_a, step_a), (fig_b, step_b) = (_planned(Path(f), name, max_rows)
                                        for f in (folder_a, folder_b))
    if fig_a is None and fig_b is None:
        return None
    thinned = [f"{tag}: every {step}th row" for tag, step in (("A", step_a), ("B", step_b))
               if step > 1]
    fig = draw(overlay(fig_a, fig_b, Path(folder_a).name, Path(folder_b).name,
                       "; ".join(thinned)))
    out = io.BytesIO()
    fig.savefig(out, format="png", dpi=100)
    plt.close(fig)
    return out.getvalue()
