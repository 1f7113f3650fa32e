"""The figures of a run, each a PNG named by what it shows (the same names for every
scenario; docs/outputs.md lists them per scenario).

A figure is planned from the run's telemetry, configuration and metrics
(:func:`plan_figures`: which figures the run has data for, as stacks of panels over a
shared time axis), then drawn (:func:`draw`). Planning leaves out what has nothing to
show: a panel none of whose lines moves by more than 2 % of its quantity's minimum span,
and a figure with no panel left. Each axis spans at least its quantity's
minimum span (a flat line is not blown up to fill it; a log axis at least a decade), and
legends sit outside the axes, to the right, clear of the data. :func:`plot_run` draws the
plan and writes the list of what it wrote (name, title, file) to ``figures.json``;
:func:`figures_of` reads it back: other code lists a run's figures with it, never by file
name.
"""

from __future__ import annotations

import functools
import io
import json
import math
import textwrap
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from app.runs.report import interval_text

__all__ = ["FIGURES", "FIGURES_FILE", "Figure", "Line", "Panel", "Panels", "draw", "figures_of",
           "panels_signature", "plan_figures", "plot_run", "pyplot", "render", "render_panels",
           "signature"]

AXES = ("x", "y", "z")

FIGURES = {
    "forces": "Forces and torques the ODS received",
    "contact_closeup": "The contact, close up",
    "velocity": "Velocity, desired (ODS) and actual (mockup)",
    "position": "Position, desired (ODS) and actual (mockup)",
    "tracking_error": "Tracking error, actual (mockup) vs desired (ODS)",
    "libration": "Pitch libration under the gravity gradient",
    "waypoints": "Waypoints flown by the GNC",
    "relative_pose": "Relative pose of the chaser to the target",
    "synchronisation": "Synchronisation with the target at the capture point",
    "target_spin": "The target's spin",
    "thrust": "Thrusters' force and wheels' torque of the GNC",
    "capture": "Capture envelope: the chaser-target state against its tolerances",
}
"""Every figure a run may have: file stem -> what it shows (the drawn title adds the
satellite names and, for the paper's scenarios, the paper's figure)."""

FIGURES_FILE = "figures.json"
"""The list of a run's figures in its folder (:func:`figures_of`)."""

PAPER_FIGURES = {
    "collision": {"forces": 8, "contact_closeup": 8, "velocity": 9, "position": 10,
                  "tracking_error": 11},
    "free-floating": {"forces": 6, "velocity": 6, "position": 6},
    "free-floating-scripted": {"forces": 6, "velocity": 6, "position": 6},
}
"""The paper's figure each of its scenarios' figures corresponds to (in the title)."""

FLAT_FRACTION = 0.02
"""A line whose peak-to-peak is under this fraction of its panel's minimum span shows
nothing (4 pixels of a 200-pixel axis: an arm's micrometre jitter, a 1e-7 m drift)."""

MIN_SPAN = {"force": 0.1, "torque": 0.01, "velocity": 1e-3, "rate": 0.1, "position": 1e-3,
            "error_mm": 0.1, "angle": 0.1, "orbit_position": 0.1, "gnc_force": 0.01,
            "gnc_torque": 1e-3, "mm": 1.0, "mm_s": 1.0}
"""The least span of an axis, per quantity, in the panel's unit (N, N m, m/s, deg/s, m,
mm, deg, orbit m, orbit N, orbit N m, mm, mm/s)."""


@dataclass
class Line:
    t: np.ndarray
    y: np.ndarray
    label: str
    style: str = "-"
    color: str | None = None
    width: float = 1.0

    def moves(self, min_span: float, magnitude: bool = False) -> bool:
        """Whether the line shows something: it varies by more than FLAT_FRACTION of the
        panel's least span, or, for a magnitude (an error), reaches that far from 0."""
        y = self.y[np.isfinite(self.y)]
        size = np.max(np.abs(y)) if magnitude and len(y) else np.ptp(y) if len(y) else 0.0
        return len(y) > 0 and float(size) > FLAT_FRACTION * min_span


@dataclass
class Panel:
    ylabel: str
    lines: list[Line]
    min_span: float
    limits: list[tuple[float, str]] = field(default_factory=list)
    """Horizontal lines (value, label): the criteria's limits."""
    log: bool = False
    shade: tuple[float, float] | None = None
    shade_label: str = "in contact"
    marks: list[tuple[float, str]] = field(default_factory=list)
    """Vertical lines (time, label): events (a waypoint reached, the capture)."""
    title: str = ""
    magnitude: bool = False
    """The lines are magnitudes (an error): a steady value is a finding, not a flat line."""

    def shows_something(self) -> bool:
        return any(line.moves(self.min_span, self.magnitude) for line in self.lines)


@dataclass
class Figure:
    name: str
    title: str
    panels: list[Panel]
    xlabel: str = "time [s]"
    text: str = ""
    """Lines of text in a panel of their own below the axes (the metrics)."""

    @property
    def file(self) -> str:
        return f"{self.name}.png"

    def entry(self) -> dict:
        return {"name": self.name, "title": self.title, "file": self.file}


# --- drawing ----------------------------------------------------------------------------


@functools.cache
def pyplot():
    """matplotlib's pyplot on the Agg backend, imported when a figure is first drawn (half a
    second: a run that draws elsewhere, app/runs/plot_process.py, never pays it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt

PANEL_HEIGHT_IN = 2.4
TEXT_COLUMNS = 120
"""Characters per line of a figure's text panel (about 10 in wide at 7.5 pt)."""
FIGURE_WIDTH_IN = 11.0
DPI = 100
PAD_IN = 0.06
"""The space between a figure's edge, or a panel's title, and what is next to it."""


def draw(figure: Figure, note: str = ""):
    """The matplotlib figure of ``figure``: its panels stacked over a shared time axis,
    legends outside the axes on the right, the text (if any) in a panel below, ``note``
    (the scaling in force) on top.

    The layout is computed here, once: every height from the font sizes (:func:`_frames`:
    the y axes' ticks are those of their final size), then the left and right margins
    from what the y axes' labels and the legends measure, the same for every panel
    (:func:`_fit_width`). The panels' place does not depend on the text: the figure is
    the panels' figure of the text-less figure with the text's strip under it
    (:func:`render` draws them apart)."""
    fig = _panels_figure(figure, note, _text_height_in(figure.text))
    if figure.text:
        _write_text(fig, figure.text, fig.axes[0].get_position().x0,
                    _text_height_in(figure.text))
    return fig


def _text_height_in(text: str) -> float:
    """The height of a figure's text strip (0 without text)."""
    return 0.0 if not text else 0.16 * (text.count("\n") + 1) + 0.3


def _new_figure(height_in: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure as MplFigure

    pyplot()  # (the Agg backend and its settings)
    fig = MplFigure(figsize=(FIGURE_WIDTH_IN, height_in), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _panels_figure(figure: Figure, note: str, text_in: float = 0.0):
    """The figure's title and panels, ``text_in`` inches left free under them."""
    n = len(figure.panels)
    height_in = PANEL_HEIGHT_IN * n + text_in + 0.6
    fig = _new_figure(height_in)
    title = figure.title if not note else f"{figure.title}\n{note}"
    fig.suptitle(title, fontsize=10, va="top", y=1.0 - PAD_IN / height_in)
    frames = _frames(figure, title, height_in, text_in)
    axes = [fig.add_axes((0.1, b, 0.7, h)) for b, h in frames]
    for ax in axes[1:]:
        ax.sharex(axes[0])
    for ax, panel in zip(axes, figure.panels, strict=True):
        _draw_panel(ax, panel)
    for ax in axes[:-1]:
        ax.tick_params(labelbottom=False)
    axes[-1].set_xlabel(figure.xlabel)
    _fit_width(fig, axes)
    return fig


def _write_text(fig, text: str, x0: float, text_in: float) -> None:
    """``text`` in the figure's bottom ``text_in`` inches, from ``x0`` (figure fraction,
    the panels' left edge)."""
    fig.text(x0, (text_in - PAD_IN) / fig.get_figheight(), text, va="top", ha="left",
             fontsize=7.5, family="monospace")


_PT_IN = 1.0 / 72.0
TITLE_LINE_IN = 10 * 1.2 * _PT_IN
PANEL_GAP_IN = 0.12
"""Between a panel's axes and the next panel's title (or axes, where it has none)."""
PANEL_TITLE_IN = 9 * 1.2 * _PT_IN + 6 * _PT_IN + PANEL_GAP_IN  # (the title pad: 6 pt)
X_AXIS_IN = (3.5 + 3.5 + 10 * 1.2 + 4 + 10 * 1.2) * _PT_IN + PAD_IN
"""Below the last panel: its ticks, their labels and the axis label (rc defaults)."""


def _frames(figure: Figure, title: str, height_in: float, text_in: float
            ) -> list[tuple[float, float]]:
    """Each panel's axes (bottom, height) in figure fractions, top to bottom: under the
    title, a title line's room above each panel's axes (its title; titled or not, the
    axis's multiplier such as "1e6" is drawn there), the x axis under the last, the text
    under it; the axes alike in height."""
    top_in = PAD_IN + TITLE_LINE_IN * (title.count("\n") + 1) + PAD_IN
    titles_in = PANEL_TITLE_IN * len(figure.panels)
    n = len(figure.panels)
    axes_in = (height_in - top_in - titles_in - X_AXIS_IN - text_in) / n
    frames, y_in = [], height_in - top_in
    for _ in figure.panels:
        y_in -= PANEL_TITLE_IN
        y_in -= axes_in
        frames.append((y_in / height_in, axes_in / height_in))
    return frames


def _fit_width(fig, axes) -> None:
    """The panels' common left and right edges: room on the left for the widest y axis
    (tick labels and label), on the right for the widest legend (it sits at 1.01 of the
    axes' width)."""
    renderer = fig.canvas.get_renderer()
    width_px = fig.bbox.width
    left_px = max(ax.bbox.x0 - ax.yaxis.get_tightbbox(renderer).x0 for ax in axes)
    legend_px = max(ax.get_legend().get_window_extent(renderer).width for ax in axes)
    pad_px = PAD_IN * fig.dpi
    left = (left_px + pad_px) / width_px
    right = (legend_px + 2 * pad_px) / width_px
    axes_w = (1.0 - left - right) / 1.01
    for ax in axes:
        pos = ax.get_position()
        ax.set_position((left, pos.y0, axes_w, pos.height))


def _draw_panel(ax, panel: Panel) -> None:
    for line in panel.lines:
        y = np.clip(line.y, 1e-12, None) if panel.log else line.y
        ax.plot(line.t, y, line.style, color=line.color, lw=line.width, label=line.label)
    for value, label in panel.limits:
        ax.axhline(value, color="k", ls="-.", lw=0.8, label=label)
    for t, label in panel.marks:
        ax.axvline(t, color="0.4", ls=":", lw=0.8, label=label)
    if panel.shade is not None:
        ax.axvspan(*panel.shade, color="0.9", label=panel.shade_label)
    ax.set_ylabel(panel.ylabel)
    if panel.title:
        ax.set_title(panel.title, fontsize=9)
    ax.grid(alpha=0.3)
    if panel.log:
        ax.set_yscale("log")
        _a_decade_at_least(ax, panel)
    else:
        _at_least(ax, panel)
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))  # a repeated mark is listed once
    ax.legend(unique.values(), unique.keys(), loc="upper left", bbox_to_anchor=(1.01, 1.0),
              fontsize=7, frameon=False, borderaxespad=0.0)


def _at_least(ax, panel: Panel) -> None:
    """The y axis spans at least the panel's minimum span, centred on the data."""
    values = [line.y[np.isfinite(line.y)] for line in panel.lines]
    values += [np.array([v]) for v, _ in panel.limits]
    values = np.concatenate([v for v in values if len(v)] or [np.zeros(1)])
    lo, hi = float(values.min()), float(values.max())
    if hi - lo < panel.min_span:
        mid = 0.5 * (lo + hi)
        ax.set_ylim(mid - 0.5 * panel.min_span, mid + 0.5 * panel.min_span)


def _a_decade_at_least(ax, panel: Panel) -> None:
    """A log axis spans at least a decade, centred (geometrically) on the data and limits."""
    values = [np.clip(line.y[np.isfinite(line.y)], 1e-12, None) for line in panel.lines]
    values += [np.array([v]) for v, _ in panel.limits if v > 0]
    values = np.concatenate([v for v in values if len(v)] or [np.ones(1)])
    lo, hi = float(values.min()), float(values.max())
    if hi < 10.0 * lo:
        mid = math.sqrt(lo * hi)
        ax.set_ylim(mid / math.sqrt(10.0), mid * math.sqrt(10.0))
    elif hi > LOG_DECADES_MAX * lo:  # an error crossing zero dips without bound: not shown
        ax.set_ylim(hi / LOG_DECADES_MAX, 2.0 * hi)


LOG_DECADES_MAX = 1e5
"""A log axis shows at most five decades below its highest value."""


def render(figure: Figure, note: str = "", panels: Panels | None = None) -> bytes:
    """The PNG of ``figure`` (:func:`draw`, :data:`DPI`): the pixels of its panels
    (:func:`render_panels`; ``panels``: those already drawn, from a figure of the same
    :func:`signature` but its text) over its text's strip. The figure is opaque: RGB,
    compressed fast (zlib level 1: a file of the size of matplotlib's own RGBA at level
    6, written in half the time)."""
    from PIL import Image

    panels = panels or render_panels(figure, note)
    pixels = panels.rgba
    if figure.text:
        text_in = _text_height_in(figure.text)
        strip = _new_figure(text_in)
        _write_text(strip, figure.text, panels.text_x0, text_in)
        pixels = np.concatenate([pixels, _pixels(strip)])
    png = io.BytesIO()
    Image.fromarray(pixels).convert("RGB").save(png, format="png", compress_level=1)
    return png.getvalue()


@dataclass
class Panels:
    """A figure's panels drawn, without its text (:func:`render_panels`)."""

    rgba: np.ndarray
    """(rows, columns, 4) uint8: the pixels."""
    text_x0: float
    """Where the text's strip starts its lines: the panels' left edge (figure fraction)."""


def render_panels(figure: Figure, note: str = "") -> Panels:
    """The pixels of ``figure``'s title and panels: all of it but its text (which the
    final metrics may change: app/runs/plot_process.py draws these before them)."""
    fig = _panels_figure(figure, note)
    return Panels(_pixels(fig), fig.axes[0].get_position().x0)


def _pixels(fig) -> np.ndarray:
    fig.canvas.draw()
    return np.array(fig.canvas.buffer_rgba())


def panels_signature(figure: Figure, note: str = "") -> tuple:
    """:func:`signature` of what :func:`render_panels` draws (all but the text)."""
    return signature(replace(figure, text=""), note)


def plot_run(rows: np.ndarray, index: dict, out_dir: Path, config, metrics: dict | None = None,
             note: str = "", rendered: dict[str, tuple[object, bytes]] | None = None
             ) -> list[Path]:
    """Draw the run's figures (:func:`plan_figures`) into ``out_dir``, and the list of them
    into ``out_dir / figures.json`` (:func:`figures_of`); the paths written. A figure an
    earlier run left there that this run does not draw is removed: the folder shows one
    run. ``rendered``: figures already drawn, name -> (:func:`signature`, PNG), each taken
    as it is where the plan's figure of that name has the same signature."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    figures = plan_figures(rows, index, config, metrics or {}) if len(rows) else []
    paths = []
    for figure in figures:
        kept = (rendered or {}).get(figure.name)
        png = kept[1] if kept and kept[0] == signature(figure, note) else render(figure, note)
        paths.append(out_dir / figure.file)
        paths[-1].write_bytes(png)
    drawn = {f.name for f in figures}
    for name in FIGURES:  # an earlier run's figure this run has not replaced goes
        stale = out_dir / f"{name}.png"
        if name not in drawn and stale.is_file():
            stale.unlink()
    listing = out_dir / FIGURES_FILE
    listing.write_text(json.dumps([f.entry() for f in figures], indent=2) + "\n")
    return [*paths, listing]


def signature(figure: Figure, note: str = "") -> tuple:
    """Everything :func:`draw` reads from ``figure`` and ``note``, as a value that compares:
    two figures of equal signature are drawn alike."""
    def line(x: Line) -> tuple:
        return (x.label, x.style, x.color, x.width, x.t.tobytes(), x.y.tobytes())

    return (figure.name, figure.title, figure.xlabel, figure.text, note,
            tuple((p.ylabel, p.min_span, tuple(p.limits), p.log, p.shade, p.shade_label,
                   tuple(p.marks), p.title, p.magnitude, tuple(map(line, p.lines)))
                  for p in figure.panels))


def figures_of(run_dir: str | Path) -> list[dict]:
    """The figures of the run in ``run_dir``: [{name, title, file}], in the order drawn
    (from its figures.json; [] when it has none, e.g. a run written without plots)."""
    path = Path(run_dir) / FIGURES_FILE
    if not path.is_file():
        return []
    return [entry for entry in json.loads(path.read_text())
            if (Path(run_dir) / entry["file"]).is_file()]


# --- planning ---------------------------------------------------------------------------


@dataclass
class _Run:
    """What the planners read: rows, their columns, the configuration and metrics."""

    rows: np.ndarray
    index: dict
    config: object
    metrics: dict

    @property
    def t(self) -> np.ndarray:
        return self.rows[:, 0]

    def cols(self, prefix: str, fields) -> np.ndarray:
        return self.rows[:, [self.index[f"{prefix}_{f}"] for f in fields]]

    def has(self, column: str) -> bool:
        return column in self.index

    def name(self, s: int) -> str:
        return self.config.satellites[s - 1].name

    @property
    def n_sat(self) -> int:
        return len(self.config.satellites)

    def carried(self, s: int) -> bool:
        return self.has(f"rob{s}_x_m")

    def title(self, stem: str, detail: str = "") -> str:
        fig = PAPER_FIGURES.get(self.config.name, {}).get(stem)
        return (FIGURES[stem] + (f": {detail}" if detail else "")
                + (f" (paper Fig. {fig})" if fig else ""))


def plan_figures(rows: np.ndarray, index: dict, config, metrics: dict) -> list[Figure]:
    """The figures the run has something to show in, in order (module doc)."""
    run = _Run(rows, index, config, metrics)
    planners = (_forces, _contact_closeup, _velocity, _position, _tracking_error,
                _libration, _waypoints, _relative_pose, _synchronisation, _target_spin,
                _thrust, _capture)
    out = []
    for planner in planners:
        figure = planner(run)
        if figure is None:
            continue
        figure.panels = [p for p in figure.panels if p.shows_something()]
        if figure.panels:
            out.append(figure)
    return out


def _xyz(t, data, label, style="-", scale=1.0) -> list[Line]:
    return [Line(t, scale * data[:, k], f"{label} {a}", style, f"C{k}")
            for k, a in enumerate(AXES)]


def _contact_window(run: _Run) -> np.ndarray:
    coll = run.metrics.get("collision")
    if not coll:
        return np.ones(len(run.rows), dtype=bool)
    t0, t1 = coll["contact_start_s"] - 0.1, coll["contact_end_s"] + 0.1
    return (run.t >= t0) & (run.t <= t1)


def _forces(run: _Run) -> Figure:
    """Per satellite: the force (R axes) and torque (body axes) the ODS received, and the
    true external force on it (dotted); with a contact, its window ± 0.1 s and the
    collision's metrics."""
    keep = _contact_window(run)
    t, panels = run.t[keep], []
    for s in range(1, run.n_sat + 1):
        p = f"sat{s}"
        lines = _xyz(t, run.cols(p, ("fx_N", "fy_N", "fz_N"))[keep], "received")
        lines += _xyz(t, run.cols(p, ("true_fx_N", "true_fy_N", "true_fz_N"))[keep], "true",
                      ":")
        panels.append(Panel("force [N]", lines, MIN_SPAN["force"],
                            title=f"{run.name(s)}: force in R (received solid, true dotted)"))
        panels.append(Panel("torque [N m]", _xyz(t, run.cols(p, ("tx_Nm", "ty_Nm", "tz_Nm"))[
            keep], "received"), MIN_SPAN["torque"], title=f"{run.name(s)}: torque, body axes"))
    coll = run.metrics.get("collision")
    return Figure("forces", run.title("forces", "the contact ± 0.1 s" if coll else ""), panels,
                  text=_collision_text(coll) if coll else "")


def _contact_closeup(run: _Run) -> Figure | None:
    """The contact window ± 0.1 s along x (the contact normal's main axis here): each
    satellite's force (received by the ODS, and true) and velocity (ODS, and the mockup
    where an arm carries it)."""
    coll = run.metrics.get("collision")
    if not coll:
        return None
    keep = _contact_window(run)
    t, force, vel = run.t[keep], [], []
    for s in range(1, run.n_sat + 1):
        c, n = f"C{s - 1}", run.name(s)
        force.append(Line(t, run.cols(f"sat{s}", ("fx_N",))[keep, 0], f"{n}: received", "-",
                          c, 1.2))
        force.append(Line(t, run.cols(f"sat{s}", ("true_fx_N",))[keep, 0], f"{n}: true", ":",
                          c, 1.2))
        vel.append(Line(t, run.cols(f"sat{s}", ("vx_mps",))[keep, 0], f"{n}: ODS", "-", c, 1.2))
        if run.carried(s):
            vel.append(Line(t, run.cols(f"rob{s}", ("vx_mps",))[keep, 0], f"{n}: mockup",
                            "--", c))
    shade = (coll["contact_start_s"], coll["contact_end_s"])
    return Figure("contact_closeup", run.title("contact_closeup", "x, shaded: in contact"),
                  [Panel("force x [N]", force, MIN_SPAN["force"], shade=shade),
                   Panel("velocity x [m/s]", vel, MIN_SPAN["velocity"], shade=shade)],
                  text=_collision_text(coll))


def _desired_actual(run: _Run, stem: str, fields, unit: str, span: str,
                    extra=None) -> Figure:
    panels = []
    for s in range(1, run.n_sat + 1):
        lines = _xyz(run.t, run.cols(f"sat{s}", fields), "ODS")
        if run.carried(s):
            lines += _xyz(run.t, run.cols(f"rob{s}", fields), "mockup", "--")
        title = (f"{run.name(s)}: ODS (desired, solid), mockup on its arm (actual, dashed)"
                 if run.carried(s) else f"{run.name(s)}: ODS (no arm carries it in this run)")
        panels.append(Panel(unit, lines, MIN_SPAN[span], title=title))
        if extra is not None:
            panels.append(extra(s))
    return Figure(stem, run.title(stem), panels)


def _velocity(run: _Run) -> Figure:
    """Per satellite: velocity in R, ODS and mockup, and the ODS's angular velocity
    (relative to R, body axes)."""
    def rate(s):
        w = np.degrees(run.cols(f"sat{s}", ("wx_radps", "wy_radps", "wz_radps")))
        return Panel("angular velocity [deg/s]", _xyz(run.t, w, "ω"), MIN_SPAN["rate"],
                     title=f"{run.name(s)}: ODS angular velocity relative to R, body axes")
    return _desired_actual(run, "velocity", ("vx_mps", "vy_mps", "vz_mps"), "velocity [m/s]",
                           "velocity", rate)


def _position(run: _Run) -> Figure:
    """Per satellite: position in R, ODS and mockup."""
    return _desired_actual(run, "position", ("x_m", "y_m", "z_m"), "position [m]", "position")


def _tracking_error(run: _Run) -> Figure | None:
    """The isochronous position error |mockup − ODS| of each carried satellite."""
    lines = [Line(run.t, 1e3 * np.linalg.norm(run.cols(f"rob{s}", ("x_m", "y_m", "z_m"))
                                              - run.cols(f"sat{s}", ("x_m", "y_m", "z_m")),
                                              axis=1), run.name(s), color=f"C{s - 1}")
             for s in range(1, run.n_sat + 1) if run.carried(s)]
    if not lines:
        return None
    return Figure("tracking_error", run.title("tracking_error"),
                  [Panel("position error [mm]", lines, MIN_SPAN["error_mm"],
                         magnitude=True)])


# --- the success criteria's figures (app/runs/success.py): orbit units and time -----------


def _success(run: _Run) -> dict:
    return run.metrics.get("success") or {}


def _orbit_time(run: _Run) -> np.ndarray:
    from app.sim.scaling import scaling_of

    return scaling_of(run.config).time * run.t


def _libration(run: _Run) -> Figure | None:
    """The pitch angle (about the orbit normal) of the librating satellite, orbit time,
    with the period measured and the theory's."""
    from app.runs.success import pitch_rad

    lib = _success(run).get("libration")
    if not lib:
        return None
    s = [x.name for x in run.config.satellites].index(lib["satellite"]) + 1
    pitch = np.degrees(pitch_rad(run.cols(f"sat{s}", ("qw", "qx", "qy", "qz"))))
    period = "-" if lib["period_s"] is None else f"{lib['period_s']:.1f} s"
    return Figure("libration", run.title("libration", lib["satellite"]),
                  [Panel("pitch [deg]", [Line(_orbit_time(run), pitch, "pitch (ODS)")],
                         MIN_SPAN["angle"],
                         title=f"period {period}, theory {lib['period_theory_s']:.1f} s at "
                               f"{lib['amplitude_deg']:.1f} deg (limit ± "
                               f"{100 * lib['limit']:g} %)")],
                  xlabel="orbit time [s]")


def _gnc_sat(run: _Run) -> int | None:
    """The first satellite with a GNC (0-based), or None."""
    return next((i for i, s in enumerate(run.config.satellites) if s.gnc is not None), None)


def _waypoint_flown(run: _Run, sat: int) -> np.ndarray:
    """Row by row, the index of the waypoint the GNC flies to (the number reached before)."""
    reached = (_success(run).get("waypoints") or {}).get("reached_at_s", [])
    count = len(run.config.satellites[sat].gnc.waypoints)
    return np.minimum(np.searchsorted(np.asarray(reached), _orbit_time(run), side="right"),
                      count - 1)


def _reference(run: _Run, sat: int) -> np.ndarray:
    """Row by row, the reference position (orbit m) of the waypoint flown."""
    from app.runs.success import reference_track

    flown = _waypoint_flown(run, sat)
    ref = np.zeros((len(run.rows), 3))
    for k in np.unique(flown):
        rows = flown == k
        ref[rows] = reference_track(run.config, run.rows, run.index, sat, int(k))[0][rows]
    return ref


def _waypoints(run: _Run) -> Figure | None:
    """The GNC satellite's position (orbit m, R axes) and the waypoint it flies to
    (dashed), and its distance to it with the GNC's tolerance; dotted: each waypoint
    reached, and the pushes on it."""
    from app.runs.success import orbit_track

    wp = _success(run).get("waypoints")
    sat = _gnc_sat(run)
    if not wp or sat is None:
        return None
    t, p, _ = orbit_track(run.config, run.rows, run.index, sat)
    ref, gnc = _reference(run, sat), run.config.satellites[sat].gnc
    marks = [(x, "waypoint reached") for x in wp["reached_at_s"]]
    from app.sim.scaling import scaling_of

    k_t = scaling_of(run.config).time
    marks += [(k_t * q.start_s, "push") for q in run.config.pulses
              if q.satellite == run.name(sat + 1)]
    fp = _success(run).get("final_position")
    limits = [(gnc.tolerance_m, "GNC tolerance")]
    if fp:
        limits.append((fp["limit_m"], "final position limit"))
    name = run.name(sat + 1)
    return Figure("waypoints", run.title("waypoints", f"{name}, {wp['reached']} of "
                                                      f"{wp['count']} reached"),
                  [Panel("position [m]", _xyz(t, p, name) + _xyz(t, ref, "waypoint", "--"),
                         MIN_SPAN["orbit_position"], marks=marks),
                   Panel("distance to the waypoint [m]",
                         [Line(t, np.linalg.norm(p - ref, axis=1), "distance", color="C3")],
                         MIN_SPAN["orbit_position"], limits=limits, log=True, marks=marks)],
                  xlabel="orbit time [s]")


def _target_of(run: _Run, sat: int) -> int | None:
    """The satellite a GNC satellite flies relative to (0-based), else the first other
    satellite, else None."""
    gnc = run.config.satellites[sat].gnc
    names = [s.name for s in run.config.satellites]
    if gnc.relative_to is not None:
        return names.index(gnc.relative_to)
    return next((i for i in range(len(names)) if i != sat), None)


def _attitude_angle(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    """The rotation angle (rad) between two rows of attitudes (wxyz)."""
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(q_a * q_b, axis=1)), 0.0, 1.0))


def _relative_pose(run: _Run) -> Figure | None:
    """The GNC satellite relative to the other one (its target): position difference in
    R (orbit m) and range, and the angle between their attitudes."""
    from app.runs.success import orbit_track

    sat = _gnc_sat(run)
    target = None if sat is None else _target_of(run, sat)
    if target is None:
        return None
    t, p_c, _ = orbit_track(run.config, run.rows, run.index, sat)
    _, p_t, _ = orbit_track(run.config, run.rows, run.index, target)
    d = p_c - p_t
    angle = np.degrees(_attitude_angle(run.cols(f"sat{sat + 1}", ("qw", "qx", "qy", "qz")),
                                       run.cols(f"sat{target + 1}", ("qw", "qx", "qy", "qz"))))
    c, g = run.name(sat + 1), run.name(target + 1)
    return Figure("relative_pose", run.title("relative_pose", f"{c} relative to {g}"),
                  [Panel("position [m]", _xyz(t, d, f"{c} − {g}")
                         + [Line(t, np.linalg.norm(d, axis=1), "range", "-", "k")],
                         MIN_SPAN["orbit_position"]),
                   Panel("attitude angle [deg]", [Line(t, angle, f"{c} to {g}", color="C4")],
                         MIN_SPAN["angle"])],
                  xlabel="orbit time [s]")


def _synchronisation(run: _Run) -> Figure | None:
    """At the capture point (the last waypoint) that turns with the target: position,
    attitude and rate errors over the run (log scale), their limits, the hold judged."""
    from app.runs.success import attitude_track, orbit_track, reference_track
    from app.sim.rotations import quat_mul, quat_to_matrix

    sync = _success(run).get("synchronisation")
    sat = _gnc_sat(run)
    if not sync or sat is None:
        return None
    gnc = run.config.satellites[sat].gnc
    last = len(gnc.waypoints) - 1
    target = [s.name for s in run.config.satellites].index(gnc.relative_to)
    t, p, _ = orbit_track(run.config, run.rows, run.index, sat)
    r_ref, _ = reference_track(run.config, run.rows, run.index, sat, last)
    q_T, w_T = attitude_track(run.config, run.rows, run.index, target)
    q_B, w_B = attitude_track(run.config, run.rows, run.index, sat)
    q_ref = quat_mul(q_T, np.asarray(gnc.attitude_wxyz, dtype=float))
    angle = _attitude_angle(q_ref, q_B)
    rate = np.linalg.norm(np.einsum("kij,kj->ki", quat_to_matrix(q_B), w_B)
                          - np.einsum("kij,kj->ki", quat_to_matrix(q_T), w_T), axis=1)
    shade = None if sync["at_s"] is None else (sync["at_s"] - sync["hold_s"], sync["at_s"])
    pos_lim = [] if sync["position_limit_m"] is None else [(sync["position_limit_m"],
                                                           "limit")]
    att_lim = [] if sync["attitude_limit_rad"] is None else [
        (math.degrees(sync["attitude_limit_rad"]), "limit")]
    return Figure("synchronisation",
                  run.title("synchronisation", f"{run.name(sat + 1)} with {gnc.relative_to}, "
                                               f"waypoint {last + 1}"),
                  [Panel("position error [m]", [Line(t, np.linalg.norm(p - r_ref, axis=1),
                                                     "position", color="C0")],
                         MIN_SPAN["orbit_position"], pos_lim, log=True, shade=shade,
                         shade_label=HELD),
                   Panel("attitude error [deg]", [Line(t, np.degrees(angle), "attitude",
                                                       color="C1")],
                         MIN_SPAN["angle"], att_lim, log=True, shade=shade, shade_label=HELD),
                   Panel("rate error [deg/s]", [Line(t, np.degrees(rate), "rate",
                                                     color="C2")],
                         MIN_SPAN["rate"], log=True, shade=shade, shade_label=HELD)],
                  xlabel="orbit time [s]")


HELD = "the hold judged"


def _target_spin(run: _Run) -> Figure | None:
    """The target's angular velocity (relative to R, its body axes, orbit deg/s) and its
    magnitude, beside the chaser's magnitude: the spin the chaser matches."""
    from app.runs.success import attitude_track

    sat = _gnc_sat(run)
    if sat is None or run.config.satellites[sat].gnc.relative_to is None:
        return None
    target = [s.name for s in run.config.satellites].index(
        run.config.satellites[sat].gnc.relative_to)
    t = _orbit_time(run)
    w_T = np.degrees(attitude_track(run.config, run.rows, run.index, target)[1])
    w_C = np.degrees(attitude_track(run.config, run.rows, run.index, sat)[1])
    name = run.name(target + 1)
    components = [Line(t, w_T[:, k], f"{name} ω {a}", style, f"C{k}", width)
                  for k, (a, style, width) in enumerate(zip(AXES, ("-", "--", ":"),
                                                            (2.5, 1.8, 1.2), strict=True))]
    magnitudes = [Line(t, np.linalg.norm(w_T, axis=1), f"|{name} ω|", "-", "k", 2.5),
                  Line(t, np.linalg.norm(w_C, axis=1), f"|{run.name(sat + 1)} ω|", "--",
                       "C3", 1.5)]
    return Figure("target_spin", run.title("target_spin", name),
                  [Panel("angular velocity [deg/s]", components, MIN_SPAN["rate"],
                         title=f"{name}: components (a line under another is drawn wider)",
                         magnitude=True),  # a steady spin is what this figure shows
                   Panel("angular velocity [deg/s]", magnitudes, MIN_SPAN["rate"],
                         title="magnitudes: the target's and the chaser's", magnitude=True)],
                  xlabel="orbit time [s]")


def _thrust(run: _Run) -> Figure | None:
    """Each GNC satellite's own thrusters' force (R axes) and wheels' torque (body axes),
    orbit N and N m."""
    panels = []
    t = _orbit_time(run)
    for s in range(1, run.n_sat + 1):
        if run.config.satellites[s - 1].gnc is None:
            continue
        p = f"sat{s}"
        panels.append(Panel("force [N]", _xyz(t, run.cols(p, ("gnc_fx_N", "gnc_fy_N",
                                                              "gnc_fz_N")), "thrust"),
                            MIN_SPAN["gnc_force"], title=f"{run.name(s)}: thrusters, R axes"))
        panels.append(Panel("torque [N m]", _xyz(t, run.cols(p, ("gnc_tx_Nm", "gnc_ty_Nm",
                                                                 "gnc_tz_Nm")), "wheels"),
                            MIN_SPAN["gnc_torque"], title=f"{run.name(s)}: wheels, body axes"))
    if not panels:
        return None
    return Figure("thrust", run.title("thrust"), panels, xlabel="orbit time [s]")


def _capture(run: _Run) -> Figure | None:
    """Docking: the target's miss from its mated offset in the chaser's frame, the
    relative speed (as the chaser sees it) and the relative angle, against the capture
    tolerances; dotted: the capture."""
    from app.sim.rotations import quat_to_matrix

    cap = run.config.capture
    if cap is None:
        return None
    c = run.config.satellite_index(cap.chaser) + 1
    g = run.config.satellite_index(cap.target) + 1
    p_c, p_t = (run.cols(f"sat{s}", ("x_m", "y_m", "z_m")) for s in (c, g))
    v_c, v_t = (run.cols(f"sat{s}", ("vx_mps", "vy_mps", "vz_mps")) for s in (c, g))
    q_c, q_t = (run.cols(f"sat{s}", ("qw", "qx", "qy", "qz")) for s in (c, g))
    R_c = quat_to_matrix(q_c)
    d_R = p_t - p_c
    w_c_R = np.einsum("kij,kj->ki", R_c, run.cols(f"sat{c}", ("wx_radps", "wy_radps",
                                                              "wz_radps")))
    v_rel = v_t - v_c - np.cross(w_c_R, d_R)  # as the chaser's rotating frame sees it
    miss = np.linalg.norm(np.einsum("kji,kj->ki", R_c, d_R) - np.asarray(cap.mated_offset_m),
                          axis=1)
    angle = np.degrees(_attitude_angle(q_c, q_t))
    event = run.metrics.get("capture") or {}
    marks = [(event["t_s"], "captured")] if event.get("captured") else []
    t = run.t
    return Figure("capture", run.title("capture", f"{cap.chaser} and {cap.target}"),
                  [Panel("miss [mm]", [Line(t, 1e3 * miss, "miss from the mated offset")],
                         MIN_SPAN["mm"], [(1e3 * cap.position_tolerance_m, "tolerance")],
                         marks=marks),
                   Panel("relative speed [mm/s]", [Line(t, 1e3 * np.linalg.norm(v_rel, axis=1),
                                                        "relative speed", color="C1")],
                         MIN_SPAN["mm_s"], [(1e3 * cap.velocity_tolerance_mps, "tolerance")],
                         marks=marks),
                   Panel("relative angle [deg]", [Line(t, angle, "relative angle",
                                                       color="C2")],
                         MIN_SPAN["angle"], [(math.degrees(cap.attitude_tolerance_rad),
                                              "tolerance")], marks=marks)])


def _collision_text(coll: dict) -> str:
    """The collision metrics as lines of text: what the mockups went through, and vs the
    ideal run; the warnings wrapped to the figure's width."""
    e, ei, err = coll["restitution"], coll.get("restitution_ideal"), coll.get("restitution_error")
    ratio = coll.get("true_impulse_ratio") or {}
    lines = [
        "restitution " + ("-" if e is None else f"{e:.3f}")
        + ("" if ei is None else f" (ideal {ei:.3f}"
           + ("" if err is None else f", error {100 * err:+.1f} %") + ")"),
        "true impulse " + ", ".join(
            f"{n} {np.linalg.norm(j):.3f} N s" + (f" ({ratio[n]:.2f}x ideal)" if n in ratio
                                                   else "")
            for n, j in coll["true_impulse_Ns"].items()),
        f"peak force {coll['peak_force_N']:.1f} N, contact {1e3 * coll['contact_duration_s']:.0f}"
        f" ms, energy absorbed {1e3 * coll['contact_energy_J']:.2f} mJ",
    ]
    interval = interval_text(coll)
    if interval:
        lines += textwrap.wrap(interval, TEXT_COLUMNS, subsequent_indent="  ")
    for warning in coll.get("warnings", []):
        lines += textwrap.wrap(f"! {warning}", TEXT_COLUMNS, subsequent_indent="  ")
    return "\n".join(lines)
