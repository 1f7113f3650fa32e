"""The viser 3D scene and GUI of the emulator.

The scene never touches the emulator: a thread of its own reads the runner's snapshots
at ~30 Hz and sends only what changed (joint angles, mockup / ODS poses, gizmos), the
traces and plots at a lower rate. GUI buttons and the transform gizmos go through the
:class:`~app.backend.service.EmulatorService`, which queues commands for the loop.

Frames: the viser world is the lab frame W (z up). Each arm is drawn at its base pose
T_W_B; frame R (the CW frame, where the ODS lives) is drawn as axes at T_W_R.
"""

from __future__ import annotations

import io
import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import viser

from app.backend.replay import ReplayRecorder
from app.backend.service import EmulatorService
from app.sim.hand import ray_box_hit
from app.sim.rotations import matrix_to_quat, quat_to_matrix
from app.sim.servo import seconds_until_beyond, seconds_until_outside
from app.sim.ur10e import HOLD_RADIUS_M, SHOULDER_B_M

log = logging.getLogger("orbit_emulator.scene")

RIGID_COLOR = (150, 165, 190)
SPONGE_COLOR = (245, 205, 50)
GHOST_COLOR = (90, 220, 255)
TRACE_COLORS = ((255, 120, 40), (60, 200, 120), (200, 90, 220), (90, 160, 255))
AXIS_COLORS = ("#e03131", "#2f9e44", "#1971c2")
GRAB_COLOR = (230, 40, 40)
BOX_COLOR = (255, 140, 0)
RAIL_COLOR = (90, 90, 110)
"""A rail: the line its carriage (the robot's base) travels."""
PLOT_WINDOW_S = 60.0
"""The live plots show the last this many seconds of scenario time."""
CAMERA_FOV_RAD = np.radians(50.0)
"""The default camera's vertical field of view."""
CAMERA_DISTANCE_M = 1.3
"""From the mockups' midpoint: a 0.2 m mockup spans about 100 px of a 630 px-high view."""
CAMERA_DIRECTION_W = np.array([0.45, -1.0, 0.5]) / np.linalg.norm([0.45, -1.0, 0.5])
"""From the mockups towards the camera: in front (-y), to the right and above."""
CAMERA_SHIFT_M = 0.15
"""The view looks this far right of the mockups: they sit left of the viewer's panel."""
GIZMO_OFFSET_W = np.array([0.0, 0.0, -0.36])
"""The gizmo (the hand's handle) sits this far from the point it holds: under the mockup,
its arrows (0.25 m) end below it, clear of the mockup (a click there grabs) and of frame
R's axes (which start at or above the mockups' height)."""
WARN_HORIZON_S = 5.0
"""The panel warns when a satellite's course leaves its arm's safety volume this soon."""

HELP = """\
**What you see.** Solid boxes: the mockups the arms carry (grey rigid, yellow sponge).
Cyan wireframes: where the orbit simulator (ODS) has each satellite; the arm keeps its
mockup on it. Coloured lines: each satellite's course. Orange box: an arm's safety volume
(its mockup's centre must stay inside; leaving it stops the run). Axes **R**: the orbit
frame's origin (x radial out, y along the track, z orbit normal).

**Your hand.** Click a mockup to grab it there (a red dot; "Grab at the centre" below
undoes it), then drag the gizmo (the hand's handle: it sits {below_cm:g} cm below the
point it holds). It is a fingertip: it **presses, never pulls**. Drag an
arrow and the hand presses the grab point that way, **{k_N_per_cm:g} N per cm** it is
pressed in, at most **{max_N:g} N** (the sensor ignores under {deadband_N:g} N). Held 10 cm
in for 1 s, satellite 1 gains up to **{dv_cm_s:.1f} cm/s**{follow_note}; once it has caught
up with the hand, the hand lets go by itself, and the satellite drifts on the way it was
pushed. Turn a ring to **twist**: {kt_Nm_per_deg:.2f} N m per degree, at most {max_Nm:g} N m (the
sensor ignores under {deadband_Nm:g} N m); held 20 degrees for 1 s about z, satellite 1
spins up by up to **{dw_deg_s:.1f} deg/s**, and the twist lets go once it turns ahead.
The arm's F/T sensor measures the push; the ODS applies it scaled ({force_scale:g} x
force, {torque_scale:g} x torque), so off the centre a press also spins the satellite.
Let go to stop; to push another way, let go and drag again.

**Plots** (the last {window_s:g} s of scenario time). The ODS's input (force in R, torque
in body axes, as measured), the satellite's velocity, angular velocity and position, and
how far each mockup is from its satellite (tracking error). Colours: x red, y green, z
blue; satellite 1 solid, satellite 2 dashed.

**Status.** t: scenario time; cycles: control cycles run (2 ms each); p50 / p99: the
median / 99th percentile of the time a cycle takes to compute (under 2000 µs keeps real
time); misses: cycles that overran their 2 ms deadline. hil: the arms carry the mockups
(hardware in the loop, simulated); ideal: no arms.

**Controls** are on the page above the view (scenario, mode, settings, Start, Stop,
Reset); this panel shows the run and holds what belongs to the 3D view.
"""

IDEAL_NOTE = """
**Ideal mode** (this run): no arms, no sensor. The boxes are drawn where the ODS has the
satellites, contact is computed between them exactly, and your push goes to the ODS as
it is (then scaled as above); there is no tracking error to plot.
"""


def hand_numbers(settings: dict) -> dict:
    """What a drag and a twist do, in numbers, for the help text (app/sim/hand.py): the
    force per cm and the most a 10 cm press held 1 s gives satellite 1 (force_scale k d
    / m; nothing under the deadband), the torque per degree and the most a 20 degree twist
    held 1 s spins it up about z (torque_scale k_t a / I_zz). A little less in fact: the
    satellite gives way as it speeds up (benchmarks/hand_drag.py)."""
    k, fs, ts = settings["hand_stiffness_Npm"], settings["force_scale"], settings["torque_scale"]
    press_N = min(k * 0.10, settings["hand_max_force_N"])
    passed_N = press_N if press_N > settings["deadband_force_N"] else 0.0
    dv = fs * passed_N / settings["satellite1_mass_kg"]
    kt = settings["hand_twist_Nmprad"]
    twist_Nm = min(kt * np.radians(20.0), settings["hand_max_torque_Nm"])
    passed_Nm = twist_Nm if twist_Nm > settings["deadband_torque_Nm"] else 0.0
    dw = ts * passed_Nm / settings["satellite1_inertia_kgm2"][2]
    return {"k_N_per_cm": k / 100.0, "max_N": settings["hand_max_force_N"],
            "deadband_N": settings["deadband_force_N"], "dv_cm_s": 100.0 * dv,
            "kt_Nm_per_deg": kt * np.pi / 180.0, "max_Nm": settings["hand_max_torque_Nm"],
            "deadband_Nm": settings["deadband_torque_Nm"], "dw_deg_s": np.degrees(dw),
            "force_scale": fs, "torque_scale": ts}


PLOT_DASH = (6.0, 4.0)
"""Satellite 2's lines in the plots (dash, gap in px)."""
PLOT_Y_AXIS_PX = 64
PLOT_PADDING_PX = (12, 12, 0, 0)


def _key_line(dash: tuple | None) -> str:
    pattern = f' stroke-dasharray="{dash[0]:g} {dash[1]:g}"' if dash else ""
    return (f'<svg width="30" height="8" style="vertical-align:middle"><line x1="0" y1="4" '
            f'x2="30" y2="4" stroke="currentColor" stroke-width="2"{pattern}/></svg>')


PLOT_KEY = (
    '<div class="plot-key" style="font-size:0.8em;padding:0 0.5em">'
    f'{_key_line(None)} satellite 1 &nbsp; {_key_line(PLOT_DASH)} satellite 2 &nbsp; '
    '<span style="color:#e03131">x</span> <span style="color:#2f9e44">y</span> '
    '<span style="color:#1971c2">z</span></div>')
"""The plots' key: uPlot's legend marks every line solid, whatever its dash."""


def default_camera(points_W: list) -> tuple[np.ndarray, np.ndarray]:
    """(position, look-at point) of the default camera for mockups at points_W: their
    midpoint seen from CAMERA_DIRECTION_W at CAMERA_DISTANCE_M (plus half their spread),
    the look-at point moved CAMERA_SHIFT_M to the camera's right."""
    pts = np.atleast_2d(np.asarray(points_W, float))
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    spread = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    distance = CAMERA_DISTANCE_M + 0.5 * max(0.0, spread - 0.7)
    right = np.cross(-CAMERA_DIRECTION_W, [0.0, 0.0, 1.0])
    look_at = centre + CAMERA_SHIFT_M * right / np.linalg.norm(right)
    return look_at + distance * CAMERA_DIRECTION_W, look_at


def trim_window(history: deque, window_s: float) -> None:
    """Drop the snapshots older than window_s of scenario time before the newest (the
    plots span a time, whatever the rate their samples came at)."""
    while len(history) > 2 and history[-1]["t_s"] - history[1]["t_s"] >= window_s:
        history.popleft()


def _load_urdf():
    import yourdfpy

    from app.backend.urdf import urdf_text

    return yourdfpy.URDF.load(
        io.StringIO(urdf_text()), build_scene_graph=True, load_meshes=True,
        build_collision_scene_graph=False, load_collision_meshes=False,
    )


@dataclass
class _ArmView:
    root: Any  # frame handle at T_W_B
    urdf: Any  # ViserUrdf
    q: np.ndarray = field(default_factory=lambda: np.full(6, np.nan))
    joints: list = field(default_factory=list)  # (frame handle, R_origin, axis, q index)
    base: tuple | None = None  # the base position shown (it moves with a rail's carriage)

    def bind_joints(self) -> None:
        """The frames of the revolute joints: only their orientation ever changes.

        ViserUrdf.update_cfg recomputes and resends every joint frame (fixed ones too)
        through yourdfpy: ~4 ms per arm. Setting the six revolute frames' orientation
        directly costs a tenth of that.
        """
        urdf = self.urdf._urdf
        names = list(urdf.actuated_joint_names)
        joints = []
        for joint, frame in zip(self.urdf._joint_map_values, self.urdf._joint_frames,
                                strict=False):
            if joint.type in ("revolute", "continuous") and joint.name in names:
                origin = np.eye(4) if joint.origin is None else np.asarray(joint.origin)
                axis = np.asarray(joint.axis, dtype=float)
                joints.append((frame, origin[:3, :3].copy(), axis / np.linalg.norm(axis),
                               names.index(joint.name)))
        self.joints = joints if len(joints) == len(names) else []

    def set_q(self, q: np.ndarray) -> None:
        if not self.joints:
            self.urdf.update_cfg(q)
            return
        for frame, R0, axis, i in self.joints:
            frame.wxyz = matrix_to_quat(R0 @ _axis_angle(axis, float(q[i])))


def _box_edges(p_min, p_max) -> np.ndarray:
    """The 12 edges of an axis-aligned box, (12, 2, 3) float32, for add_line_segments."""
    lo, hi = np.asarray(p_min, float), np.asarray(p_max, float)
    corners = np.array([[(hi if (k >> a) & 1 else lo)[a] for a in range(3)]
                        for k in range(8)])
    edges = [(k, k | (1 << a)) for k in range(8) for a in range(3) if not (k >> a) & 1]
    return np.array([[corners[i], corners[j]] for i, j in edges], dtype=np.float32)


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix of `angle` about the unit vector `axis` (Rodrigues)."""
    x, y, z = axis
    c, s = np.cos(angle), np.sin(angle)
    C = 1.0 - c
    return np.array([
        [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
        [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
        [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
    ])


@dataclass
class _SatView:
    index: int
    mockup: Any
    ghost: Any
    gizmo: Any
    size_m: tuple = (0.1, 0.1, 0.1)
    grab_B: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """Where the hand holds the mockup (body axes, from the COM): a click picks it."""
    grab_marker: Any = None
    gizmo_offset_W: np.ndarray = field(default_factory=lambda: GIZMO_OFFSET_W.copy())
    """From the grab point to the gizmo."""
    T_W_C: np.ndarray = field(default_factory=lambda: np.eye(4))
    """The mockup's pose as last drawn."""
    trace_points: deque = field(default_factory=lambda: deque(maxlen=600))
    trace: Any = None
    trace_version: int = 0
    trace_sent: int = 0
    dragging: bool = False
    last_mockup: tuple = ()
    last_ghost: tuple = ()
    last_gizmo: tuple = ()


class EmulatorScene:
    """Builds the viser scene and keeps it in step with the runner's snapshots."""

    def __init__(self, server: viser.ViserServer, service: EmulatorService,
                 rate_hz: float = 30.0) -> None:
        self.server = server
        self.service = service
        self.rate_hz = rate_hz
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._urdf_model = None
        self._arms: dict[tuple, _ArmView] = {}
        self._active_arms: list[_ArmView] = []
        self._sats: list[_SatView] = []
        self._layout_key: tuple | None = None
        self._generation: int | None = None
        self._camera_for: tuple | None = None  # the layout's default camera
        self._framed: set = set()  # the viewers sent it
        self._built_generation: int | None = None
        self._history: deque = deque()  # the snapshots of the last PLOT_WINDOW_S
        self.plot_window_s = PLOT_WINDOW_S
        self._plots_have_data = False
        self._frame_R = None
        self._boxes: list = []
        self.replay = ReplayRecorder(server)
        """The 3D replay of the run going on, or of the last one (app/backend/replay.py)."""
        self._recorded_generation: int | None = None
        self.update_cost_s: deque = deque(maxlen=300)  # wall time of each scene update
        self._last_slow = 0.0
        self._build_static()
        self._build_gui()

    # --- construction ---------------------------------------------------------------

    def _build_static(self) -> None:
        scene = self.server.scene
        scene.configure_environment_map(hdri=None)
        scene.add_light_ambient("/lights/ambient", intensity=0.6)
        scene.add_light_directional(
            "/lights/key", intensity=2.0, position=(2.0, -3.0, 4.0), cast_shadow=False
        )
        scene.add_light_hemisphere("/lights/hemi", intensity=0.5)
        scene.set_up_direction("+z")
        scene.add_grid("/floor", width=4.0, height=4.0, cell_size=0.25, position=(0, 0, 0))
        self.server.initial_camera.fov = float(CAMERA_FOV_RAD)
        self._frame_camera([np.array([0.0, 0.0, 1.0])])

    def _frame_camera(self, points_W: list) -> None:
        """The default camera: looking at the mockups' midpoint from CAMERA_DIRECTION_W,
        CAMERA_DISTANCE_M away, shifted right so that they sit left of the panel; set for
        the viewers connected too (a new layout: a new scene to look at)."""
        position, look_at = default_camera(points_W)
        self.server.initial_camera.position = tuple(position)
        self.server.initial_camera.look_at = tuple(look_at)
        self._camera_for = (tuple(position), tuple(look_at))
        self._framed = set()  # the viewers sent this camera (the initial camera is only a
        self._frame_viewers()  # new viewer's)

    def _frame_viewers(self) -> None:
        """Send the layout's camera to each viewer not sent it yet: one whose camera was
        not reported when the layout changed gets it at a later update."""
        if self._camera_for is None:
            return
        position, look_at = self._camera_for
        for client in self.server.get_clients().values():
            if client.client_id in self._framed:
                continue
            try:
                client.camera.position = position
                client.camera.look_at = look_at
                self._framed.add(client.client_id)
            except (AssertionError, ValueError):  # its camera not reported yet
                log.debug("client %s: camera not set yet", client.client_id)

    def _build_gui(self) -> None:
        gui = self.server.gui
        self.gui_status = gui.add_markdown("**status** idle")
        self.gui_warning = gui.add_markdown("")
        with gui.add_folder("Help", expand_by_default=False):
            self.gui_help = gui.add_markdown("")
        with gui.add_folder("Hand"):
            self.gui_grab = gui.add_markdown("grabbing: the centre of mass")
            self.gui_grab_centre = gui.add_button("Grab at the centre")

        @self.gui_grab_centre.on_click
        def _(_event) -> None:
            for sv in self._sats:
                self._set_grab(sv, np.zeros(3))

        with gui.add_folder("Plots"):
            self.gui_plot_key = gui.add_html(PLOT_KEY)
            self.plots = {
                key: self._add_plot(title)
                for key, title in (
                    ("force", "Force on the ODS (N, R)"),
                    ("torque", "Torque on the ODS (N m, body)"),
                    ("velocity", "Velocity (m/s, R)"),
                    ("omega", "Angular velocity (deg/s, body)"),
                    ("position", "Position (m, R)"),
                    ("tracking", "Tracking error |actual - ODS| (mm)"),
                )
            }
        self._plot_series: tuple | None = None

    def _add_plot(self, title: str):
        return self.server.gui.add_uplot(
            data=(np.zeros(0), np.zeros(0)),  # nothing before the first cycle
            series=({"label": "t (s)"}, {"label": "-", "stroke": "#888"}),
            title=title,
            scales={"x": {"time": False}},
            # room for a signed label ("-0.0035") left of the y axis, and for the top
            # label's upper half above the plot area (uPlot's 50 px and 0 px cut both)
            axes=({}, {"size": PLOT_Y_AXIS_PX}),
            padding=PLOT_PADDING_PX,
            aspect=1.6,
        )

    def _sync_gui(self, snap: dict) -> None:
        """The panel's help says what the run that is there does (its hand, its scales)."""
        settings = snap.get("settings")
        if settings:
            numbers = hand_numbers(settings)
            follow_cm_s = 100.0 * self.service.push_max_dv_mps()[0]
            note = (f" (**more than the arm follows**, about {follow_cm_s:.0f} cm/s at a "
                    f"time: press lightly and briefly)"
                    if snap["mode"] == "hil" and numbers["dv_cm_s"] > follow_cm_s else "")
            self.gui_help.content = HELP.format(
                **numbers, follow_note=note, below_cm=-100.0 * GIZMO_OFFSET_W[2],
                window_s=PLOT_WINDOW_S) + (IDEAL_NOTE if snap["mode"] == "ideal" else "")

    def _arm_view(self, name: str, T_W_B: np.ndarray) -> _ArmView:
        key = (name, tuple(np.round(T_W_B, 6).ravel()))
        view = self._arms.get(key)
        if view is None:
            from viser.extras import ViserUrdf

            if self._urdf_model is None:
                self._urdf_model = _load_urdf()
            root_name = f"/arms/{name}_{len(self._arms)}"
            root = self.server.scene.add_frame(
                root_name, show_axes=False, wxyz=matrix_to_quat(T_W_B[:3, :3]),
                position=T_W_B[:3, 3],
            )
            urdf = ViserUrdf(self.server, self._urdf_model, root_node_name=root_name)
            view = _ArmView(root=root, urdf=urdf)
            view.bind_joints()
            self._arms[key] = view
        view.root.visible = True
        return view

    def _rebuild(self, snap: dict) -> None:
        """(Re)build the nodes that depend on the scenario: arms, mockups, gizmos."""
        layout = snap["layout"]
        info = {
            "T_W_R": np.array(layout["T_W_R"]),
            "arms": [(name, np.array(T)) for name, T in layout["arms"]],
            "sats": [(n, tuple(size), mat) for n, size, mat in layout["satellites"]],
        }
        key = (
            tuple(np.round(info["T_W_R"], 6).ravel()),
            tuple((n, tuple(np.round(T, 6).ravel())) for n, T in info["arms"]),
            tuple(info["sats"]),
        )
        self._history.clear()
        self._plot_series = None
        if key == self._layout_key:
            for sv in self._sats:
                sv.trace_points.clear()
                sv.trace_version += 1
                self._set_grab(sv, np.zeros(3))  # a new run: the hand holds the centre
            return
        self._layout_key = key
        self._frame_camera([np.asarray(sat["position_W_m"]) for sat in snap["satellites"]])
        scene = self.server.scene
        T_W_R = info["T_W_R"]
        if self._frame_R is None:
            self._frame_R = scene.add_frame(
                "/frame_R", axes_length=0.25, axes_radius=0.008,
                wxyz=matrix_to_quat(T_W_R[:3, :3]), position=T_W_R[:3, 3],
            )
            scene.add_label("/frame_R/label", "R", position=(0.0, 0.0, 0.05))
        else:
            self._frame_R.wxyz = matrix_to_quat(T_W_R[:3, :3])
            self._frame_R.position = T_W_R[:3, 3]
        for view in self._arms.values():
            view.root.visible = False
        self._active_arms = [self._arm_view(n, T) for n, T in info["arms"]]
        for sv in self._sats:
            for h in (sv.mockup, sv.ghost, sv.gizmo, sv.trace):
                if h is not None:
                    h.remove()
        self._sats = []
        for i, (name, size, material) in enumerate(info["sats"]):
            color = SPONGE_COLOR if material == "sponge" else RIGID_COLOR
            mockup = scene.add_box(f"/mockups/{i}_{name}", color=color, dimensions=size,
                                   material="toon5" if material == "sponge" else "standard")
            ghost = scene.add_box(f"/ods/{i}_{name}", color=GHOST_COLOR, dimensions=size,
                                  wireframe=True)
            gizmo = scene.add_transform_controls(
                f"/gizmo/sat{i + 1}", scale=0.35, depth_test=False,
                line_width=3.0,
            )
            sv = _SatView(index=i, mockup=mockup, ghost=ghost, gizmo=gizmo, size_m=size)
            sv.grab_marker = scene.add_icosphere(
                f"/mockups/{i}_{name}/grab", radius=0.012, color=GRAB_COLOR)
            self._attach_gizmo(sv)
            self._attach_grab(sv)
            self._sats.append(sv)
        for h in self._boxes:
            h.remove()
        rails = [ends for ends in layout.get("rails_W_m", []) if ends is not None]
        self._boxes = [  # the rails, a line along each carriage's travel
            scene.add_line_segments(f"/rails/{k}", points=np.array([ends], dtype=float),
                                    colors=RAIL_COLOR, thickness=6.0,
                                    thickness_units="screen")
            for k, ends in enumerate(rails)
        ] + [
            scene.add_line_segments(f"/safety/{k}", points=_box_edges(lo, hi),
                                    colors=BOX_COLOR, thickness=1.5,
                                    thickness_units="screen")
            for k, (lo, hi) in enumerate(layout.get("safety_boxes_W_m", []))
        ]

    def _attach_gizmo(self, sv: _SatView) -> None:
        svc = self.service

        @sv.gizmo.on_update
        async def _(event) -> None:  # async: runs on viser's loop, keeps phase order
            hand_W = tuple(np.asarray(event.target.position) - sv.gizmo_offset_W)
            if event.phase in ("start", "update"):  # the hand presses and twists
                sv.dragging = True
                svc.hand(sv.index, hand_W, tuple(sv.grab_B), tuple(event.target.wxyz))
            else:  # it lets go; the next grab starts square again
                svc.hand(sv.index, None)
                sv.dragging = False
                sv.gizmo.wxyz = (1.0, 0.0, 0.0, 0.0)

    def _attach_grab(self, sv: _SatView) -> None:
        @sv.mockup.on_click
        def _(event) -> None:
            if sv.dragging:
                return
            hit = ray_box_hit(event.ray_origin, event.ray_direction, sv.T_W_C, sv.size_m)
            if hit is not None:
                self._set_grab(sv, hit)

    def _set_grab(self, sv: _SatView, point_B: np.ndarray) -> None:
        """The hand holds mockup `sv` at point_B (body axes): the marker and the gizmo go
        there."""
        sv.grab_B = np.asarray(point_B, float)
        sv.grab_marker.position = tuple(sv.grab_B)
        if not sv.dragging:
            p = sv.T_W_C[:3, :3] @ sv.grab_B + sv.T_W_C[:3, 3] + sv.gizmo_offset_W
            sv.gizmo.position = tuple(p)
            sv.last_gizmo = tuple(np.round(p, 4))
        text = "; ".join(
            f"satellite {v.index + 1}: " + (
                "the centre of mass" if not v.grab_B.any() else
                f"({', '.join(f'{1e3 * c:+.0f}' for c in v.grab_B)}) mm from the centre "
                f"(body axes)")
            for v in self._sats if v is sv or v.grab_B.any()) or "the centre of mass"
        self.gui_grab.content = f"grabbing: {text}"

    @property
    def generation(self) -> int | None:
        """Generation of the run the scene has been built for (None before the first)."""
        return self._built_generation

    # --- the update thread ----------------------------------------------------------

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="viser-scene", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        self.replay.finish()  # a run still going: its replay so far is kept too

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        next_t = time.monotonic()
        while not self._stop.is_set():
            try:
                t0 = time.perf_counter()
                self.update(self.service.runner.snapshot())
                self.update_cost_s.append(time.perf_counter() - t0)
            except Exception:
                log.exception("scene update failed")
            next_t += period
            delay = next_t - time.monotonic()
            if delay < 0:
                next_t = time.monotonic()
                delay = 0.0
            self._stop.wait(delay)

    def update(self, snap: dict | None) -> None:
        if not snap:
            return
        if snap["generation"] != self._generation:
            self.replay.finish()  # the run before ended or was replaced
            self._generation = snap["generation"]
            self._rebuild(snap)
            self._sync_gui(snap)
            self._built_generation = snap["generation"]
        if snap["loop"]["cycles"] and (not self._history
                                       or self._history[-1]["t_s"] != snap["t_s"]):
            self._history.append(snap)  # (nothing to plot before the first cycle)
            trim_window(self._history, self.plot_window_s)
        running = snap["status"] == "running"
        if running and self._recorded_generation != snap["generation"]:
            self.replay.start(snap["generation"])
            self._recorded_generation = snap["generation"]
        self.replay.tick(snap["t_s"])
        self._frame_viewers()
        now = time.monotonic()
        with self.server.atomic():
            for view, rob in zip(self._active_arms, snap["robots"], strict=False):
                base = rob.get("base_position_W_m")
                if base is not None and tuple(np.round(base, 4)) != view.base:
                    view.base = tuple(np.round(base, 4))
                    view.root.position = view.base  # the carriage moved the base
                q = np.asarray(rob["q_rad"])
                if np.max(np.abs(q - view.q), initial=np.inf) > 2e-4 or np.isnan(view.q[0]):
                    view.set_q(q)
                    view.q = q
            by_sat = {r["satellite"] - 1: r for r in snap["robots"]}
            for sv, sat in zip(self._sats, snap["satellites"], strict=False):
                ghost = (tuple(np.round(sat["position_W_m"], 4)),
                         tuple(np.round(sat["attitude_W_wxyz"], 4)))
                rob = by_sat.get(sv.index)
                mock = ghost if rob is None else (
                    tuple(np.round(rob["mockup_position_W_m"], 4)),
                    tuple(np.round(rob["mockup_attitude_W_wxyz"], 4)),
                )
                if ghost != sv.last_ghost:
                    sv.ghost.position, sv.ghost.wxyz = ghost[0], ghost[1]
                    sv.last_ghost = ghost
                if mock != sv.last_mockup:
                    sv.mockup.position, sv.mockup.wxyz = mock[0], mock[1]
                    sv.last_mockup = mock
                    sv.T_W_C = np.eye(4)
                    sv.T_W_C[:3, :3] = quat_to_matrix(np.array(mock[1]))
                    sv.T_W_C[:3, 3] = mock[0]
                grab = tuple(np.round(sv.T_W_C[:3, :3] @ sv.grab_B + sv.T_W_C[:3, 3]
                                      + sv.gizmo_offset_W, 4))
                if not sv.dragging and grab != sv.last_gizmo:
                    sv.gizmo.position = grab
                    sv.last_gizmo = grab
                p = np.asarray(sat["position_W_m"])
                if not sv.trace_points or np.linalg.norm(p - sv.trace_points[-1]) > 0.002:
                    sv.trace_points.append(p)
                    sv.trace_version += 1
        if not running and self.replay.recording:
            self.replay.finish()  # the run's last frame is in
        if now - self._last_slow > 0.25:  # traces, plots, status: 4 Hz
            self._last_slow = now
            self._update_traces()
            self._update_plots()
            self._update_status(snap)

    def _update_traces(self) -> None:
        for sv in self._sats:
            if sv.trace_version == sv.trace_sent or len(sv.trace_points) < 2:
                continue
            pts = np.asarray(sv.trace_points, dtype=np.float32)
            segs = np.ascontiguousarray(np.stack([pts[:-1], pts[1:]], axis=1))
            color = TRACE_COLORS[sv.index % len(TRACE_COLORS)]
            colors = np.broadcast_to(np.array(color, np.uint8), segs.shape).copy()
            if sv.trace is None:
                sv.trace = self.server.scene.add_line_segments(
                    f"/traces/sat{sv.index + 1}", points=segs, colors=colors,
                    thickness=2.0, thickness_units="screen",
                )
            else:
                sv.trace.points = segs
                sv.trace.colors = colors
            sv.trace_sent = sv.trace_version

    def _update_plots(self) -> None:
        hist = list(self._history)
        if len(hist) < 2:
            if self._plots_have_data:  # a new run (a reset): the last one's curves go
                for plot in self.plots.values():
                    plot.data = tuple(np.zeros(0) for _ in plot.data)
                self._plots_have_data = False
            return
        self._plots_have_data = True
        t = np.array([h["t_s"] for h in hist])
        n_sat = len(hist[-1]["satellites"])
        n_rob = len(hist[-1]["robots"])
        shape = (n_sat, n_rob)
        new_series = self._plot_series != shape
        if new_series:
            self._plot_series = shape
            self._series = {}
            for key in ("force", "torque", "velocity", "omega", "position"):
                ser = [{"label": "t (s)"}]
                for i in range(n_sat):
                    for a, axis in enumerate("xyz"):
                        s = {"label": f"s{i + 1} {axis}", "stroke": AXIS_COLORS[a], "width": 1.5}
                        if i:
                            s["dash"] = PLOT_DASH
                            s["label"] += " (dashed)"  # uPlot's legend draws all solid
                        ser.append(s)
                self._series[key] = tuple(ser)
            self._series["tracking"] = tuple(
                [{"label": "t (s)"}] + [
                    {"label": f"robot {r + 1}", "stroke": AXIS_COLORS[r % 3], "width": 1.5}
                    for r in range(n_rob)
                ] + ([] if n_rob else [{"label": "no arms (ideal)", "stroke": "#999999"}])
            )
        data_key = {"force": ("applied_force_N", 1.0),
                    "torque": ("applied_torque_Nm", 1.0),
                    "velocity": ("velocity_mps", 1.0),
                    "omega": ("omega_radps", 180.0 / np.pi),
                    "position": ("position_m", 1.0)}
        x_range = {"x": {"time": False, "auto": False, "range": [float(t[0]), float(t[-1])]}}
        for key, (field_name, unit) in data_key.items():
            arr = unit * np.array([[s.get(field_name, (0.0, 0.0, 0.0)) for s in h["satellites"]]
                                   for h in hist])  # T,N,3
            cols = [t] + [arr[:, i, a] for i in range(n_sat) for a in range(3)]
            plot = self.plots[key]
            if new_series:
                plot.series = self._series[key]
            plot.scales = x_range  # the time axis spans the data, no more
            plot.data = tuple(np.ascontiguousarray(c, dtype=np.float64) for c in cols)
        if n_rob:
            err = np.array([[np.nan if r["tracking_error_m"] is None
                             else r["tracking_error_m"] * 1e3 for r in h["robots"]]
                            for h in hist])
            cols = [t] + [err[:, r] for r in range(n_rob)]
        else:
            cols = [t, np.zeros_like(t)]
        if new_series:
            self.plots["tracking"].series = self._series["tracking"]
        self.plots["tracking"].scales = x_range
        self.plots["tracking"].data = tuple(np.ascontiguousarray(c) for c in cols)

    def _update_status(self, snap: dict) -> None:
        loop = snap["loop"]
        pending = self.service.pending_start
        if pending is not None:
            text = (f"**{pending[0]}** ({pending[1]}) — **checking its course before the "
                    "start** (pre-flight, a few seconds)")
        elif loop["cycles"] == 0 and snap["status"] in ("idle", "starting"):
            text = (f"**{snap['scenario']}** ({snap['mode']}) — **not started**  \n"
                    "On Start each arm first carries its mockup onto its cyan wireframe "
                    "(the satellite's start pose); then the orbit runs.")
        else:
            text = (
                f"**{snap['scenario']}** ({snap['mode']}) — **{snap['status']}**  \n"
                f"t = {snap['t_s']:.2f} s · cycles {loop['cycles']} · "
                f"p50 {loop['cycle_time_us']['p50']:.0f} µs · p99 "
                f"{loop['cycle_time_us']['p99']:.0f} µs · misses {loop['deadline_misses']}"
            )
        if snap.get("reason"):
            text += f"  \n{snap['reason']}"
        if text != getattr(self, "_last_status", None):
            self.gui_status.content = text
            self._last_status = text
        warning = panel_warning(snap)
        if warning != self.gui_warning.content:
            self.gui_warning.content = warning


def panel_warning(snap: dict) -> str:
    """The panel's warnings: the run's own (from its configuration, shown before Start,
    e.g. satellites the F/T noise can spin), then the course's (course_warning)."""
    lines = [f"⚠ {text}" for text in snap.get("warnings", [])]
    course = course_warning(snap)
    return "  \n".join(lines + ([course] if course else []))


def course_warning(snap: dict, horizon_s: float = WARN_HORIZON_S) -> str:
    """A warning for each carried satellite whose course (straight on at its ODS velocity)
    leaves its arm's safety volume within horizon_s while the run goes on; "" if none."""
    if snap["status"] != "running":
        return ""
    layout = snap["layout"]
    R_W_R = np.asarray(layout["T_W_R"])[:3, :3]
    lines = []
    arms = layout.get("arms", [])
    for k, (rob, (lo, hi)) in enumerate(zip(snap["robots"], layout.get("safety_boxes_W_m", []),
                                            strict=False)):
        sat = snap["satellites"][rob["satellite"] - 1]
        v_W = R_W_R @ np.asarray(sat["velocity_mps"])
        t_box = seconds_until_outside(sat["position_W_m"], v_W, lo, hi)
        t_reach, whose = np.inf, "its shoulder"
        rails = layout.get("rails_W_m", [])
        if k < len(arms):  # the reach: usually the nearer limit (the box is the last net)
            T_W_B = np.asarray(arms[k][1])
            shoulder_B = T_W_B[:3, :3] @ np.asarray(SHOULDER_B_M)
            if k < len(rails) and rails[k] is not None:  # from the line the rail sweeps
                ends = np.asarray(rails[k]) + shoulder_B
                t_reach = _seconds_until_beyond_segment(sat["position_W_m"], v_W, ends,
                                                        HOLD_RADIUS_M, horizon_s)
                whose = "its shoulder's line along the rail"
            else:
                t_reach = seconds_until_beyond(sat["position_W_m"], v_W,
                                               shoulder_B + T_W_B[:3, 3], HOLD_RADIUS_M)
        if min(t_box, t_reach) <= horizon_s:
            where = (f"out of {rob['name']}'s reach ({HOLD_RADIUS_M:g} m from {whose})"
                     if t_reach < t_box else f"out of {rob['name']}'s safety volume")
            lines.append(f"⚠ satellite {rob['satellite']} goes {where} in "
                         f"{min(t_box, t_reach):.1f} s on its course: the run will stop")
    return "  \n".join(lines)


def _seconds_until_beyond_segment(p_W_m, v_W_mps, ends_W_m, radius_m: float,
                                  horizon_s: float, samples: int = 200) -> float:
    """When a point moving straight from p_W_m at v_W_mps first gets farther than radius_m
    from the segment ends_W_m (2, 3), to horizon_s / samples (inf if not within horizon_s)."""
    a, b = np.asarray(ends_W_m[0], float), np.asarray(ends_W_m[1], float)
    d = b - a
    t = np.linspace(0.0, horizon_s, samples + 1)
    p = np.asarray(p_W_m, float) + t[:, None] * np.asarray(v_W_mps, float)
    u = np.clip((p - a) @ d / (d @ d), 0.0, 1.0)
    beyond = np.linalg.norm(p - a - u[:, None] * d, axis=1) > radius_m
    return float(t[np.argmax(beyond)]) if beyond.any() else float("inf")
