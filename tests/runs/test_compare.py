"""Two kept runs compared (app/runs/compare.py): the settings that differ, and one figure of
both runs merged panel by panel, run A solid and run B dashed, the legend naming them."""

from __future__ import annotations

import numpy as np
import pytest

from app.runs.compare import UnknownFigure, check_figure, overlay, settings_diff
from app.runs.plots import Figure, Line, Panel


def _figure(name: str, offset: float, extra_panel: bool = False) -> Figure:
    t = np.linspace(0.0, 1.0, 11)
    panels = [Panel("velocity [m/s]", [Line(t, t + offset, "ODS x", "-", "C0"),
                                       Line(t, t - offset, "mockup x", "--", "C0")],
                    1e-3, title="cubesat", shade=(0.2, 0.4 + offset))]
    if extra_panel:
        panels.append(Panel("force [N]", [Line(t, 0 * t, "true x", ":", "C1")], 0.1,
                            title="sponge"))
    return Figure(name, "title", panels)


def test_the_overlay_merges_matching_panels_a_solid_b_dashed():
    fig = overlay(_figure("velocity", 0.0), _figure("velocity", 0.5, extra_panel=True),
                  "run-a", "run-b")
    assert [p.title for p in fig.panels] == ["cubesat", "sponge"]  # matched, then B's own
    merged = fig.panels[0]
    labels = [line.label for line in merged.lines]
    assert labels[:2] == ["A run-a", "B run-b"]  # the legend names the runs first
    assert labels[2:] == ["A ODS x", "A mockup x", "B ODS x", "B mockup x"]
    assert [line.style for line in merged.lines[2:]] == ["-", "-", "--", "--"]
    np.testing.assert_allclose(merged.lines[4].y, np.linspace(0, 1, 11) + 0.5)  # B's data
    # the same quantity has one colour in both runs, and another quantity another
    assert merged.lines[2].color == merged.lines[4].color != merged.lines[3].color
    assert merged.shade == (0.2, 0.4)  # A's contact
    assert "A run-a (solid) against B run-b (dashed)" in fig.title
    assert fig.panels[1].lines[2].label == "B true x"


def test_the_overlay_drops_a_panel_s_note_of_its_own_line_styles():
    """A run's forces panel says "(received solid, true dotted)"; in the overlay every line
    is restyled (A solid, B dashed, the kind by colour), so the note would mislead: it is
    dropped, and the panels still match by the rest of the title."""
    t = np.linspace(0.0, 1.0, 5)
    lines = [Line(t, t, "received x", "-", "C0"), Line(t, t, "true x", ":", "C0")]
    forces = Figure("forces", "forces", [Panel("force [N]", lines, 0.1,
                                               title="cubesat: force in R (received solid, "
                                                     "true dotted)")])
    fig = overlay(forces, forces, "run-a", "run-b")
    assert [p.title for p in fig.panels] == ["cubesat: force in R"]
    assert len(fig.panels[0].lines) == 2 + 4


def test_the_overlay_of_a_figure_only_one_run_has_says_so():
    fig = overlay(None, _figure("velocity", 0.5), "run-a", "run-b")
    assert "A has no such figure" in fig.title
    assert [line.label for line in fig.panels[0].lines][2:] == ["B ODS x", "B mockup x"]


def test_the_settings_that_differ_by_dotted_key():
    a = {"scenario": "collision", "mode": "hil",
         "config": {"loop": {"duration_s": 1.2, "seed": 3},
                    "satellites": [{"name": "cubesat", "position_m": [-0.16, 0, 0]}]}}
    b = {"scenario": "collision", "mode": "ideal",
         "config": {"loop": {"duration_s": 0.6, "seed": 3},
                    "satellites": [{"name": "cubesat", "position_m": [-0.2, 0, 0]}],
                    "extra": {"k": 1}}}
    assert settings_diff(a, b) == [
        {"key": "extra.k", "a": None, "b": 1},
        {"key": "loop.duration_s", "a": 1.2, "b": 0.6},
        {"key": "mode", "a": "hil", "b": "ideal"},
        {"key": "satellites.0.position_m", "a": [-0.16, 0, 0], "b": [-0.2, 0, 0]}]
    assert settings_diff(a, a) == []


def test_a_figure_name_is_checked():
    assert check_figure("contact_closeup") == "contact_closeup"
    with pytest.raises(UnknownFigure, match="figure 'fig8': not a run's figure "
                                            r"\(one of forces, contact_closeup"):
        check_figure("fig8")
