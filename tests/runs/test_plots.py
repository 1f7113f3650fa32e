"""The figures of a run (app/runs/plots.py), for every library scenario run headless for a
short while: files named by what they show, the figures each scenario's success criteria
are about, none empty or degenerate, legends clear of the axes, no jump at t = 0; the
summary's net and pushed Δv and its criteria (app/runs/report.py)."""

from __future__ import annotations

import json

import matplotlib.pyplot as plt
import numpy as np
import pytest

from app.runs.headless import run_scenario
from app.runs.plots import FIGURES, draw, figures_of, plan_figures
from app.runs.report import run_summary
from app.scenarios import load_scenario

RUNS = {  # scenario: (mode, duration_s): short, but each shows what its figures are about
    "collision": ("ideal", 3.3),  # the contact at 3.1 s
    "collision-hil": ("hil", 0.4),
    "free-floating": ("hil", 0.4),
    "free-floating-scripted": ("hil", 4.5),  # the +x push at 1 s and the -x push at 4 s
    "free-flying": ("ideal", 1.0),
    "gravity-stabilised": ("hil", 1.0),
    "rendezvous": ("ideal", 6.0),
    "tumbling-target": ("ideal", 1.0),
    "docking": ("ideal", 1.0),
}

EXPECTED = {  # the figures each must have (the criteria's first)
    "collision": {"forces", "contact_closeup", "velocity", "position"},
    "collision-hil": {"velocity", "position", "tracking_error"},
    "free-floating": set(),  # at rest, untouched: nothing moves, nothing to show
    "free-floating-scripted": {"forces", "velocity", "position", "tracking_error"},
    "free-flying": {"waypoints", "thrust", "position"},
    "gravity-stabilised": {"libration", "tracking_error"},
    "rendezvous": {"waypoints", "relative_pose"},
    "tumbling-target": {"waypoints", "relative_pose", "synchronisation", "target_spin",
                        "thrust"},
    "docking": {"capture", "thrust", "relative_pose"},
}

FLOOR = {"[N]": 0.05, "[N m]": 0.005, "[m/s]": 5e-4, "[deg/s]": 0.05, "[m]": 5e-4,
         "[mm]": 0.05, "[deg]": 0.05, "[mm/s]": 0.5}
"""The least y span a linear axis may have, by the unit in its label."""


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict:
    out = {}
    for key, (mode, duration_s) in RUNS.items():
        folder = tmp_path_factory.mktemp(key)
        result = run_scenario(load_scenario(key.removesuffix("-hil")), mode=mode,
                              duration_s=duration_s, out_dir=folder, with_ideal=False)
        out[key] = (result, folder)
    return out


def test_every_scenario_s_figures_are_named_by_content_and_listed(runs):
    for key, (_, folder) in runs.items():
        pngs = {p.stem for p in folder.glob("*.png")}
        listed = figures_of(folder)
        assert [f["file"] for f in listed] == [f"{f['name']}.png" for f in listed]
        assert {f["name"] for f in listed} == pngs, key
        assert pngs <= set(FIGURES) and not any(n.startswith("fig") for n in pngs), key
        assert EXPECTED[key] <= pngs, (key, pngs)
        assert json.loads((folder / "figures.json").read_text()) == listed
        paper = key.startswith(("collision", "free-floating"))
        for f in listed:
            assert f["title"].startswith(FIGURES[f["name"]])
            if not paper:
                assert "paper" not in f["title"], (key, f)
    assert figures_of(runs["free-floating"][1]) == []  # no empty figure written
    assert not list(runs["free-floating"][1].glob("*.png"))
    titles = {f["name"]: f["title"] for f in figures_of(runs["collision"][1])}
    assert titles["forces"].endswith("(paper Fig. 8)")
    assert titles["velocity"].endswith("(paper Fig. 9)")


def test_a_run_into_a_folder_replaces_the_earlier_run_s_figures(runs, tmp_path):
    """An earlier run's figure in the folder that this run (at rest: it draws none) does
    not draw is removed; other files stay: a folder's figures are one run's."""
    from app.runs.plots import plot_run

    (tmp_path / "forces.png").write_bytes(b"\x89PNG earlier run")
    (tmp_path / "notes.png").write_bytes(b"mine")
    rest, _ = runs["free-floating"]
    plot_run(rest.emulator.telemetry.rows(), rest.emulator.telemetry.index, tmp_path,
             rest.emulator.config, rest.metrics)
    assert not (tmp_path / "forces.png").exists() and figures_of(tmp_path) == []
    assert (tmp_path / "notes.png").read_bytes() == b"mine"


def _drawn(result):
    rows, index = result.emulator.telemetry.rows(), result.emulator.telemetry.index
    for figure in plan_figures(rows, index, result.emulator.config, result.metrics):
        fig = draw(figure)
        fig.canvas.draw()
        yield figure, fig
        plt.close(fig)


def _unit(label: str) -> str:
    return label[label.rindex("["):] if "[" in label else ""


def test_no_figure_is_empty_or_degenerate_and_no_legend_covers_data(runs):
    """Every axis drawn has a line that moves, spans at least its unit's floor (a log
    axis at least a decade), and its legend lies outside it: the old tumbling-target
    figures (all-zero forces, a position autoscaled to 1e-7 m) cannot come back."""
    for key, (result, _) in runs.items():
        for figure, fig in _drawn(result):
            renderer = fig.canvas.get_renderer()
            data_axes = [ax for ax in fig.axes if ax.axison]
            assert data_axes, (key, figure.name)
            for ax in data_axes:
                what = (key, figure.name, ax.get_ylabel())
                curves = [ln.get_ydata() for ln in ax.get_lines()
                          if len(np.atleast_1d(ln.get_xdata())) > 2]
                lo, hi = ax.get_ylim()
                if ax.get_yscale() == "log":
                    assert any(np.ptp(y) > 0 for y in curves), what
                    assert hi / lo >= 9.99, what
                else:
                    floor = FLOOR[_unit(ax.get_ylabel())]
                    steady = any(k in ax.get_ylabel() for k in ("error", "angular"))
                    size = ((lambda y: np.max(np.abs(y))) if steady  # an error's or a
                            else np.ptp)  # spin's steady level is a finding
                    assert any(size(y) > 0.01 * floor for y in curves), what
                    assert hi - lo >= floor, what
                box = ax.get_legend().get_window_extent(renderer)
                assert not box.overlaps(ax.get_window_extent(renderer)), what


def test_the_tumbling_target_shows_the_target_s_spin(runs):
    result, _ = runs["tumbling-target"]
    spin = next(f for f in plan_figures(result.emulator.telemetry.rows(),
                                        result.emulator.telemetry.index,
                                        result.emulator.config, result.metrics)
                if f.name == "target_spin")
    components, magnitudes = spin.panels  # both shown: a steady spin is the finding
    magnitude = next(line for line in magnitudes.lines if line.label == "|target ω|")
    np.testing.assert_allclose(magnitude.y, 2.0, rtol=1e-3)  # its 2 deg/s, throughout
    assert [line.style for line in components.lines] == ["-", "--", ":"]  # none hidden


def test_no_jump_at_the_start_of_the_velocity_figure(runs):
    """The first samples of each plotted velocity continue into the next: the first step
    is no larger than the largest of the following ones, or than a micrometre a second
    (the arms ran up to their satellites' velocity before t = 0: the mockup moves with
    its satellite from the first cycle; nothing is differenced against an unset previous
    value). And the mockup's recorded velocity is its recorded position's rate of change
    from the start."""
    result, _ = runs["collision-hil"]
    figure = next(f for f in plan_figures(result.emulator.telemetry.rows(),
                                          result.emulator.telemetry.index,
                                          result.emulator.config, result.metrics)
                  if f.name == "velocity")
    for panel in figure.panels:
        for line in panel.lines:
            steps = np.abs(np.diff(line.y[:50]))
            assert steps[0] <= max(steps[1:].max(), 1e-6), (panel.ylabel, line.label)
    rows, ix = result.emulator.telemetry.rows(), result.emulator.telemetry.index
    t = rows[:, 0]
    for s in (1, 2):
        x = rows[:, [ix[f"rob{s}_{a}_m"] for a in "xyz"]]
        v = rows[:, [ix[f"rob{s}_v{a}_mps"] for a in "xyz"]]
        rate = np.diff(x, axis=0) / np.diff(t)[:, None]
        np.testing.assert_allclose(rate[:40], v[1:41], atol=2e-3)


def test_the_summary_labels_net_and_pushed_delta_v_and_lists_the_criteria(runs):
    """Two opposite 3 cm/s pushes (20 N for 0.3 s on a 1 kg mockup at force scale 0.005):
    the net change nearly cancels, the pushes' sum is their 6 cm/s. The criteria judged
    are named with their values and limits."""
    result, _ = runs["free-floating-scripted"]
    sat = result.metrics["satellites"][0]
    assert sat["delta_v_mps"] < 0.005
    assert sat["delta_v_pushed_mps"] == pytest.approx(2 * 20.0 * 0.3 * 0.005 / 1.0, rel=0.05)
    text = run_summary(result.metrics)
    assert "net dv" in text and "pushes |dv|" in text
    assert f"{sat['delta_v_pushed_mps']:.3f} m/s" in text
    summary = run_summary(runs["tumbling-target"][0].metrics)
    assert "2 criteria judged: waypoints NOT MET, synchronisation NOT MET" in summary
    assert "(limits 10 mm, 1.00 deg)" in summary
    assert "reached in order (required: all)" in summary
    libration = run_summary(runs["gravity-stabilised"][0].metrics)
    assert "1 criterion judged: libration" in libration and "(limit 2 %)" in libration
    rendezvous = run_summary(runs["rendezvous"][0].metrics)
    assert "no_contact passed" in rendezvous and "final_position" in rendezvous
    assert "(limit 0.5 m)" in rendezvous


def test_an_axis_multiplier_has_room_above_its_panel_titled_or_not():
    """The layout is computed once (app/runs/plots.py _frames): an axis whose values call
    for a multiplier ("1e6" over its top-left corner) gets it in the room above its
    axes, titled or not: between the panel above's axes and its own there is the
    multiplier's height and half a tick label's (a tick label at the edge of the panel
    above reaches that far), and a title clears it."""
    from app.runs.plots import Figure, Line, Panel

    t = np.linspace(0.0, 1.0, 50)
    panels = [Panel("big", [Line(t, 3e6 * np.sin(6 * t) + 1e6 * k, "a")], 1.0,
                    title="titled" if k == 1 else "") for k in range(3)]
    fig = draw(Figure("synthetic", "three panels", panels))
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    axes = fig.axes
    for above, below in zip(axes, axes[1:], strict=False):
        offset = below.yaxis.get_offset_text()
        assert offset.get_text(), "the values call for a multiplier"
        multiplier = offset.get_window_extent(renderer)
        tick = above.get_yticklabels()[0].get_window_extent(renderer)
        assert above.bbox.y0 - below.bbox.y1 >= multiplier.height + tick.height / 2
        if below.get_title():
            assert not multiplier.overlaps(below.title.get_window_extent(renderer))
    plt.close("all")
