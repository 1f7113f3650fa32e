"""PNG plots of a run, like the paper's Fig. 6 (free-floating) and Figs. 8-11 (collision)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from app.runs.report import interval_text  # noqa: E402

AXES = ("x", "y", "z")


PLOT_FILES = ("fig6_free_floating.png", "fig8b_contact_closeup.png", "fig8_forces.png",
              "fig9_velocity.png", "fig10_position.png", "fig11_position_error.png")
"""The figures :func:`plot_run` may write (those a run has data for)."""


def _save(fig, path: Path, note: str) -> None:
    """Save a figure with the run's note (the scaling in force) above its titles."""
    if note:
        fig.suptitle(note, fontsize=8, color="0.35")
    fig.savefig(path, dpi=100)


def _series(rows, index, prefix, fields):
    return rows[:, [index[f"{prefix}_{f}"] for f in fields]]


def _three(ax, t, data, label, unit, style="-"):
    for k, a in enumerate(AXES):
        ax.plot(t, data[:, k], style, color=f"C{k}", lw=1.0, label=f"{label} {a}")
    ax.set_ylabel(unit)
    ax.grid(alpha=0.3)


def plot_free_floating(rows, index, out_dir: Path, sat: int = 1, note: str = "") -> list[Path]:
    """Fig. 6: force and torque the ODS received (measured: force in R, torque in body
    axes), the satellite's velocity, angular velocity and position."""
    t = rows[:, 0]
    fig, axes = plt.subplots(5, 1, figsize=(9, 12), sharex=True, layout="constrained")
    pre = f"sat{sat}"
    _three(axes[0], t, _series(rows, index, pre, ("fx_N", "fy_N", "fz_N")), "F", "force [N]")
    _three(axes[1], t, _series(rows, index, pre, ("tx_Nm", "ty_Nm", "tz_Nm")), "T",
           "torque [N m]")
    _three(axes[2], t, _series(rows, index, pre, ("vx_mps", "vy_mps", "vz_mps")), "v",
           "velocity [m/s]")
    _three(axes[3], t, np.degrees(_series(rows, index, pre,
                                          ("wx_radps", "wy_radps", "wz_radps"))),
           "ω", "angular velocity [deg/s]")
    _three(axes[4], t, _series(rows, index, pre, ("x_m", "y_m", "z_m")), "p", "position [m]")
    axes[0].set_title(f"Satellite {sat}: force (in R) and torque (body axes) from the F/T "
                      "sensor, and the ODS response")
    axes[-1].set_xlabel("time [s]")
    for ax in axes:
        ax.legend(loc="upper right", fontsize=7, ncol=3)
    path = out_dir / "fig6_free_floating.png"
    _save(fig, path, note)
    plt.close(fig)
    return [path]


def plot_contact_closeup(rows, index, out_dir: Path, n_sat: int, collision: dict,
                         note: str = "") -> Path:
    """The contact window ± 0.1 s: along the contact normal's main axis (x here), each
    satellite's force (received by the ODS, and the true contact force) and velocity
    (ODS, and the mockup where an arm carries it): how the impact went, cycle by cycle."""
    t0, t1 = collision["contact_start_s"] - 0.1, collision["contact_end_s"] + 0.1
    keep = (rows[:, 0] >= t0) & (rows[:, 0] <= t1)
    w, t = rows[keep], rows[keep, 0]
    text = _collision_text(collision)
    fig, (ax_f, ax_v) = _axes_over_text(2, text, panel_height_in=3.0)
    for s in range(1, n_sat + 1):
        c = f"C{s - 1}"
        ax_f.plot(t, w[:, index[f"sat{s}_fx_N"]], "-", color=c, lw=1.2,
                  label=f"sat {s}: received by the ODS")
        ax_f.plot(t, w[:, index[f"sat{s}_true_fx_N"]], ":", color=c, lw=1.2,
                  label=f"sat {s}: true contact")
        ax_v.plot(t, w[:, index[f"sat{s}_vx_mps"]], "-", color=c, lw=1.2,
                  label=f"sat {s}: ODS")
        if f"rob{s}_vx_mps" in index:
            ax_v.plot(t, w[:, index[f"rob{s}_vx_mps"]], "--", color=c, lw=1.0,
                      label=f"sat {s}: mockup (arm)")
    for ax in (ax_f, ax_v):
        ax.axvspan(collision["contact_start_s"], collision["contact_end_s"], color="0.9")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=7, ncol=2)
    ax_f.set_ylabel("force x [N]")
    ax_v.set_ylabel("velocity x [m/s]")
    ax_v.set_xlabel("time [s]")
    ax_f.set_title("The contact, close up (shaded: in contact)")
    path = out_dir / "fig8b_contact_closeup.png"
    _save(fig, path, note)
    plt.close(fig)
    return path


TEXT_COLUMNS = 120
"""Characters per line of a figure's text panel (9 in wide at 7.5 pt)."""


def _axes_over_text(n_panels: int, text: str, panel_height_in: float):
    """A figure of ``n_panels`` stacked axes (shared time axis) with ``text`` in a panel of
    its own below them, sized to the text: nothing overlaps the curves or leaves the page."""
    n_lines = text.count("\n") + 1
    text_in = 0.16 * n_lines + 0.3
    fig = plt.figure(figsize=(9, panel_height_in * n_panels + text_in),
                     layout="constrained")
    grid = fig.add_gridspec(n_panels + 1, 1,
                            height_ratios=[panel_height_in] * n_panels + [text_in])
    axes = [fig.add_subplot(grid[0])]
    axes += [fig.add_subplot(grid[k], sharex=axes[0]) for k in range(1, n_panels)]
    for ax in axes[:-1]:
        ax.tick_params(labelbottom=False)
    box = fig.add_subplot(grid[n_panels])
    box.axis("off")
    box.text(0.0, 1.0, text, transform=box.transAxes, va="top", ha="left", fontsize=7.5,
             family="monospace")
    return fig, axes


def _collision_text(coll: dict) -> str:
    """The collision metrics as lines of text: what the mockups went through, and vs the
    ideal run; the warnings wrapped to the figure's width."""
    import textwrap

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


def plot_collision(rows, index, out_dir: Path, n_sat: int, n_rob: int,
                   collision: dict | None = None, note: str = "") -> list[Path]:
    """Figs. 8-11: forces in R, desired vs actual velocity and position, position error.

    Fig. 8 zooms on the contact (its window ± 0.1 s) when ``collision`` (the metrics) is
    given, and shows them."""
    t = rows[:, 0]
    sats = list(range(1, n_sat + 1))
    paths = []

    if collision is not None:  # the metrics in a text panel below the forces
        fig, panels = _axes_over_text(n_sat, _collision_text(collision), panel_height_in=3.0)
        axes = np.array(panels)[:, None]
    else:
        fig, axes = plt.subplots(n_sat, 1, figsize=(9, 3 * n_sat), sharex=True,
                                 squeeze=False, layout="constrained")
    for ax, s in zip(axes[:, 0], sats, strict=True):
        _three(ax, t, _series(rows, index, f"sat{s}", ("fx_N", "fy_N", "fz_N")), "F", "force [N]")
        _three(ax, t, _series(rows, index, f"sat{s}", ("true_fx_N", "true_fy_N", "true_fz_N")),
               "true", "force [N]", ":")
        ax.set_title(f"Satellite {s}: force received by the ODS (solid) and true contact (dotted)")
        ax.legend(loc="upper right", fontsize=7, ncol=2)
        if collision is not None:
            ax.set_xlim(collision["contact_start_s"] - 0.1, collision["contact_end_s"] + 0.1)
    axes[-1, 0].set_xlabel("time [s]")
    paths.append(out_dir / "fig8_forces.png")
    _save(fig, paths[-1], note)
    plt.close(fig)
    if collision is not None:
        paths.append(plot_contact_closeup(rows, index, out_dir, n_sat, collision, note))

    for name, fields, rfields, unit in (
        ("fig9_velocity.png", ("vx_mps", "vy_mps", "vz_mps"), ("vx_mps", "vy_mps", "vz_mps"),
         "velocity [m/s]"),
        ("fig10_position.png", ("x_m", "y_m", "z_m"), ("x_m", "y_m", "z_m"), "position [m]"),
    ):
        fig, axes = plt.subplots(n_sat, 1, figsize=(9, 3 * n_sat), sharex=True, squeeze=False,
                                 layout="constrained")
        for ax, s in zip(axes[:, 0], sats, strict=True):
            _three(ax, t, _series(rows, index, f"sat{s}", fields), "ODS", unit)
            if s <= n_rob:
                _three(ax, t, _series(rows, index, f"rob{s}", rfields), "robot", unit, "--")
            ax.set_title(f"Satellite {s}: desired (ODS, solid) vs actual (robot, dashed)")
            ax.legend(loc="upper right", fontsize=7, ncol=2)
        axes[-1, 0].set_xlabel("time [s]")
        paths.append(out_dir / name)
        _save(fig, paths[-1], note)
        plt.close(fig)

    if n_rob:
        fig, ax = plt.subplots(figsize=(9, 4), layout="constrained")
        for s in range(1, min(n_sat, n_rob) + 1):
            d = _series(rows, index, f"rob{s}", ("x_m", "y_m", "z_m")) - _series(
                rows, index, f"sat{s}", ("x_m", "y_m", "z_m")
            )
            ax.plot(t, 1e3 * np.linalg.norm(d, axis=1), label=f"satellite {s}")
        ax.set_ylabel("position error [mm]")
        ax.set_xlabel("time [s]")
        ax.set_title("Isochronous position error, actual (robot) vs desired (ODS)")
        ax.grid(alpha=0.3)
        ax.legend()
        paths.append(out_dir / "fig11_position_error.png")
        _save(fig, paths[-1], note)
        plt.close(fig)
    return paths


def plot_run(rows: np.ndarray, index: dict, out_dir: Path, n_sat: int, n_rob: int,
             collision: dict | None = None, note: str = "") -> list[Path]:
    """The paper's figures for a run: Fig. 6 style with one satellite, Figs. 8-11 with more
    (``collision``: the run's collision metrics, shown on Fig. 8; ``note``: a line on top
    of every figure, the scaling in force)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    if len(rows) == 0:
        return []
    if n_sat == 1:
        return plot_free_floating(rows, index, out_dir, note=note)
    return plot_collision(rows, index, out_dir, n_sat, n_rob, collision, note)
