"""The web process's heavy reads (app/backend/service.py, app/backend/ring.py): the
telemetry ring read by file, whole or in chunks, and the shared, one-at-a-time
computation of metrics."""

from __future__ import annotations

import numpy as np
import pytest

from app.backend.service import SharedReads


def _ring_and_writer(capacity: int):
    """A run's ring (app/backend/ring.py), its shared memory, and a TelemetryBuffer over
    that storage that writes rows as the loop does."""
    from app.backend.ring import RunTelemetry, attach_ring
    from app.scenarios import load_scenario
    from app.sim.telemetry import TelemetryBuffer

    config = load_scenario("collision")
    config = config.model_copy(update={"loop": config.loop.model_copy(
        update={"telemetry_capacity": capacity})})
    ring = RunTelemetry(config, "ideal")
    shm, data, counters = attach_ring(ring.name, capacity, len(ring.columns))
    buffer = TelemetryBuffer(ring.columns, capacity)
    buffer.use_storage(data, counters)
    return ring, shm, buffer


def _ring_with_rows(n_rows: int, capacity: int = 100):
    """A run's ring into which n_rows rows were written as the loop writes them, and the
    rows it must hold."""
    ring, shm, buffer = _ring_and_writer(capacity)
    k = np.arange(n_rows, dtype=float)[:, None]
    written = 0.002 * k + np.arange(len(ring.columns)) / 7.0
    for row in written:
        buffer.append(row)
    del buffer
    shm.close()
    return ring, written[max(0, n_rows - capacity):]


@pytest.mark.parametrize("n_rows", [0, 1, 99, 100, 101, 250])
def test_the_ring_reads_by_file_what_the_loop_wrote_whole_or_in_chunks(n_rows):
    """The web process reads the ring with pread (never through the mapping): all of it
    (metrics), or a few rows at a time (a CSV download), oldest first, wrapped or not."""
    ring, expected = _ring_with_rows(n_rows)
    try:
        first, rows = ring.numbered_rows()
        assert first == max(0, n_rows - 100) and np.array_equal(rows, expected)
        chunks = list(ring.chunks(chunk_rows=7))
        if first > 0:  # wrapped: the stream begins an eighth of the ring later, aligned
            first = -(-(first + 100 // 8) // 7) * 7
        starts = sorted({first, *range((first // 7 + 1) * 7, n_rows, 7)}) if n_rows else []
        assert [f for f, _ in chunks] == starts  # whole chunks begin at multiples of 7
        assert all(len(c) <= 7 for _, c in chunks)
        joined = np.concatenate([c for _, c in chunks]) if chunks else rows[:0]
        assert np.array_equal(joined, expected[len(expected) - (n_rows - first):])
    finally:
        ring.release()
    assert list(ring.chunks()) == []  # released: nothing to read, no error
    with pytest.raises(FileNotFoundError):
        ring.numbered_rows()


def test_a_wrapped_ring_streamed_while_the_loop_writes_has_no_gap():
    """A CSV stream pauses between chunks as its client takes them while the loop goes on
    overwriting the ring's oldest rows: the rows streamed are contiguous all the same
    (the soak once found 27 rows missing mid-stream, at a burst of slow cycles)."""
    capacity, chunk = 160, 8
    ring, shm, buffer = _ring_and_writer(capacity)
    row = np.zeros(len(ring.columns))
    written = 0

    def write(n, into):
        nonlocal written
        for _ in range(n):
            row[0] = written
            into.append(row)
            written += 1

    try:
        write(3 * capacity + 5, buffer)  # wrapped, its oldest row in the middle of a chunk
        numbers = []
        for first, rows in ring.reader().chunks(chunk):
            numbers.extend(rows[:, 0])
            assert rows[0, 0] == first
            write(chunk // 2 + 3, buffer)  # the client is slow: the loop writes meanwhile
        steps = np.diff(numbers)
        assert len(numbers) > capacity // 2 and np.all(steps == 1), steps[steps != 1]
    finally:
        del buffer
        shm.close()
        ring.release()


class _Loop:
    def __init__(self):
        self.snap = {"generation": 1, "status": "running", "loop": {"cycles": 0}}

    def __call__(self):
        return self.snap


def test_reads_are_shared_while_fresh_and_recomputed_when_the_run_changes():
    loop, calls = _Loop(), []
    reads = SharedReads(loop, max_age_s=60.0)

    def compute():
        calls.append(dict(loop.snap, loop=dict(loop.snap["loop"])))
        return len(calls)

    assert reads.get("m", compute) == 1
    loop.snap["loop"]["cycles"] = 500
    assert reads.get("m", compute) == 1  # within max_age_s: the same answer
    loop.snap["status"] = "finished"
    assert reads.get("m", compute) == 2  # the run finished: its last rows are not missed
    assert reads.get("m", compute) == 2  # nothing ran since
    loop.snap["generation"] = 2
    assert reads.get("m", compute) == 3
    reads.max_age_s = 0.0
    loop.snap["loop"]["cycles"] = 501
    assert reads.get("m", compute) == 4  # stale and rows came: computed anew


def test_the_panel_warns_when_a_satellite_s_course_leaves_its_arm_s_safety_volume():
    """course_warning: a carried satellite whose straight course leaves its arm's safety
    volume within the horizon is named with the time; at rest, or not running, no
    warning."""
    from app.backend.scene import course_warning

    R_turned = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # R in W
    T_W_R = np.eye(4)
    T_W_R[:3, :3] = R_turned

    def snap(velocity_R, status="running"):
        return {"status": status,
                "layout": {"T_W_R": T_W_R.tolist(),
                           "safety_boxes_W_m": [[[-1.5, -1.5, 0.05], [1.5, 1.5, 2.4]]]},
                "robots": [{"name": "ceiling", "satellite": 1}],
                "satellites": [{"position_W_m": [0.0, 1.0, 1.0], "velocity_mps": velocity_R}]}

    # 0.2 m/s along R's x is W's +y: the wall at y = 1.5 is 0.5 m away, 2.5 s
    assert course_warning(snap([0.2, 0.0, 0.0])) == (
        "⚠ satellite 1 goes out of ceiling's safety volume in 2.5 s on its course: the run "
        "will stop")
    assert course_warning(snap([0.05, 0.0, 0.0])) == ""  # 10 s: beyond the 5 s horizon
    assert course_warning(snap([0.0, 0.0, 0.0])) == ""
    assert course_warning(snap([0.2, 0.0, 0.0], status="finished")) == ""


def test_the_panel_shows_the_run_s_own_warnings_before_the_course_s():
    """panel_warning: the snapshot's warnings (from the run's configuration) show whatever
    the status, before Start too; a course warning follows them."""
    from app.backend.scene import course_warning, panel_warning

    snap = {"status": "idle", "warnings": ["satellite 'chaser': noise can spin it"],
            "layout": {"T_W_R": np.eye(4).tolist(),
                       "safety_boxes_W_m": [[[-1.5, -1.5, 0.05], [1.5, 1.5, 2.4]]]},
            "robots": [{"name": "floor", "satellite": 1}],
            "satellites": [{"position_W_m": [0.0, 1.0, 1.0], "velocity_mps": [0, 0.2, 0]}]}
    assert panel_warning(snap) == "⚠ satellite 'chaser': noise can spin it"
    snap["status"] = "running"
    assert panel_warning(snap) == ("⚠ satellite 'chaser': noise can spin it  \n"
                                   + course_warning(snap))
    assert panel_warning({**snap, "warnings": []}) == course_warning(snap) != ""


def test_the_panel_warns_before_a_satellite_s_course_leaves_its_arm_s_reach():
    """The reach (HOLD_RADIUS_M from the shoulder) is usually nearer than the box: the
    warning names it, with the time from |p + v t - shoulder| = r."""
    from app.backend.scene import course_warning
    from app.sim.servo import seconds_until_beyond
    from app.sim.ur10e import HOLD_RADIUS_M, SHOULDER_B_M

    snap = {"status": "running",
            "layout": {"T_W_R": np.eye(4).tolist(), "arms": [["floor", np.eye(4).tolist()]],
                       "safety_boxes_W_m": [[[-1.5, -1.5, 0.05], [1.5, 1.5, 2.4]]]},
            "robots": [{"name": "floor", "satellite": 1}],
            "satellites": [{"position_W_m": [0.0, 0.5, 1.0], "velocity_mps": [0.0, 0.2, 0.0]}]}
    height = 1.0 - SHOULDER_B_M[2]
    t = (np.sqrt(HOLD_RADIUS_M**2 - height**2) - 0.5) / 0.2  # 1.88 s; the box: 5 s
    assert course_warning(snap) == (
        f"⚠ satellite 1 goes out of floor's reach ({HOLD_RADIUS_M:g} m from its shoulder) "
        f"in {t:.1f} s on its course: the run will stop")
    assert seconds_until_beyond([0, 0.5, 1.0], [0, 0.2, 0], SHOULDER_B_M,
                                HOLD_RADIUS_M) == pytest.approx(t, rel=1e-12)
    assert seconds_until_beyond([0, 0, 2.0], [0, 0, 0], [0, 0, 0], 1.0) == 0.0  # beyond
    assert seconds_until_beyond([0, 0, 0.5], [0, 0, 0], [0, 0, 0], 1.0) == np.inf
    assert seconds_until_beyond([0, 0, 0.5], [0, 0, -1.0], [0, 0, 0], 1.0) == 1.5  # through


def test_the_csv_cache_keeps_the_newest_whole_chunks_of_one_ring_within_its_budget():
    from app.backend.service import CsvChunks

    cache = CsvChunks(budget=10)
    for number in (0, 4, 8):
        cache.put("ring-a", number, b"abcd")
    assert cache.get("ring-a", 0) is None  # 12 bytes > 10: the oldest went
    assert cache.get("ring-a", 4) == cache.get("ring-a", 8) == b"abcd"
    assert cache.get("ring-b", 8) is None  # another ring's rows are not these
    cache.put("ring-b", 0, b"xy")
    assert cache.get("ring-a", 8) is None and cache.get("ring-b", 0) == b"xy"
    cache.put("ring-b", 4, b"x" * 11)  # over the whole budget: not kept
    assert cache.get("ring-b", 4) is None and cache.get("ring-b", 0) == b"xy"
    cache.put("ring-b", 8, b"zz")
    cache.forget_before("ring-a", 8)  # another ring: nothing to forget here
    assert cache.get("ring-b", 0) == b"xy"
    cache.forget_before("ring-b", 8)  # the ring wrapped past row 8: its older chunks go
    assert cache.get("ring-b", 0) is None and cache.get("ring-b", 8) == b"zz"
    cache.put("ring-b", 12, b"x" * 8)  # the forgotten bytes no longer count
    assert cache.get("ring-b", 8) == b"zz"
    cache.clear()
    assert cache.get("ring-b", 12) is None


def test_the_push_limit_keeps_room_for_weight_bias_noise_hand_and_overlapping_pulses():
    """push_limit: the sensor's range less m·|g|, |bias|, 6 sigma of noise, the hand's cap
    and the most the scripted pulses push that satellite at once (pulses that only touch
    end to end do not add up; pulses on another satellite do not count)."""
    from app.backend.service import push_limit
    from app.config import merge_overrides
    from app.scenarios import load_scenario

    cfg = merge_overrides(load_scenario("collision"), {
        "sensor": {"range_force_N": 150.0, "bias_force_N": [3.0, 0.0, 4.0],
                   "noise_force_N": 0.5},
        "hand": {"max_force_N": 10.0}, "lab": {"gravity_mps2": [0.0, 0.0, -10.0]},
        "satellites": {"0": {"mass_kg": 2.0}}})
    name0, name1 = cfg.satellites[0].name, cfg.satellites[1].name
    base = 150.0 - 2.0 * 10.0 - 5.0 - 6 * 0.5 - 10.0  # satellite 0: a 2 kg mockup
    assert push_limit(cfg, 0)[0] == pytest.approx(base)
    pulses = [{"satellite": name0, "start_s": 1.0, "end_s": 2.0, "force_N": [3.0, 4.0, 0.0]},
              {"satellite": name0, "start_s": 1.5, "end_s": 3.0, "force_N": [0.0, 0.0, 7.0]},
              {"satellite": name0, "start_s": 3.0, "end_s": 4.0, "force_N": [9.0, 0.0, 0.0]},
              {"satellite": name1, "start_s": 0.0, "end_s": 9.0, "force_N": [50.0, 0, 0]}]
    limit_N, why = push_limit(merge_overrides(cfg, {"pulses": pulses}), 0)
    assert limit_N == pytest.approx(base - 12.0)  # 5 + 7 at once; 7 and 9 only touch
    assert why == ("the F/T sensor's 150 N range less the mockup's weight 20.0 N, the bias "
                   "5.0 N, 6 sigma of noise 3.0 N, the scripted pulses' 12.0 N and the "
                   "hand's 10 N")
    heavy = merge_overrides(cfg, {"satellites": {"0": {"mass_kg": 20.0}}})
    assert push_limit(heavy, 0)[0] == 0.0  # a mockup too heavy for any push: never negative


def test_the_twist_limit_keeps_room_for_the_weight_s_moment_bias_noise_and_the_hand():
    """twist_limit: the sensor's torque range less m |g| |mockup_offset| (the weight's
    moment about the sensor), |bias|, 6 sigma of noise, the gizmo's twist cap and its
    press cap at the box's far corner (lever + half diagonal); never negative.
    push_max_dw scales with the attitude bound."""
    from app.backend.service import push_max_dw, twist_limit
    from app.config import merge_overrides
    from app.scenarios import load_scenario

    cfg = merge_overrides(load_scenario("free-floating"), {
        "sensor": {"range_torque_Nm": 12.0, "bias_torque_Nm": [0.3, 0.0, 0.4],
                   "noise_torque_Nm": 0.05},
        "hand": {"max_force_N": 10.0, "max_torque_Nm": 1.0},
        "lab": {"gravity_mps2": [0.0, 0.0, -10.0]},
        "satellites": {"0": {"mass_kg": 2.0, "size_m": [0.2, 0.2, 0.1]}},
        "robots": {"0": {"mockup_offset_m": [0.0, 0.0, 0.1]}}})
    hand = 1.0 + 10.0 * (0.1 + 0.15)  # the far corner: 0.5 |(0.2, 0.2, 0.1)| = 0.15 m
    expected = 12.0 - 2.0 * 10.0 * 0.1 - 0.5 - 6 * 0.05 - hand
    limit, why = twist_limit(cfg, 0)
    assert limit == pytest.approx(expected)
    assert why == ("the F/T sensor's 12 N m range less the mockup's weight's moment 2.00 N m, "
                   "the bias 0.50 N m, 6 sigma of noise 0.30 N m and the hand's 3.50 N m")
    heavy = merge_overrides(cfg, {"satellites": {"0": {"mass_kg": 20.0}}})
    assert twist_limit(heavy, 0)[0] == 0.0
    assert push_max_dw(cfg)[0] == pytest.approx(0.24)
    tight = merge_overrides(cfg, {"loop": {"max_tracking_error_rad": 0.125}})
    assert push_max_dw(tight)[0] == pytest.approx(0.12)


def test_a_push_s_course_leaves_where_the_straight_line_does_and_bends_under_a_fast_orbit():
    """course_exit: at the real orbit rate (800 km, 1e-3 rad/s) the CW course over 5 s is
    the straight line, so it leaves the reach when seconds_until_beyond says (within its
    0.01 s sampling), and the box likewise; under a time scale that makes the orbit rate
    ~1 rad/s, the course bends and leaves elsewhere: where the CW state transition crosses
    the box's floor (the out-of-plane motion swings down)."""
    from app.backend.service import COURSE_STEP_S, course_exit
    from app.scenarios import load_scenario
    from app.sim.orbital import cw_state_transition, orbit_rate
    from app.sim.scaling import scaling_of
    from app.sim.servo import seconds_until_beyond, seconds_until_outside
    from app.sim.ur10e import HOLD_RADIUS_M, SHOULDER_B_M

    cfg = load_scenario("free-floating")
    state = {"layout": {"T_W_R": np.eye(4).tolist(), "arms": [["floor", np.eye(4).tolist()]],
                        "safety_boxes_W_m": [[[-1.5, -1.5, 0.05], [1.5, 1.5, 2.4]]]},
             "robots": [{"name": "floor", "satellite": 1}],
             "satellites": [{"position_m": [0.0, 0.5, 1.0], "velocity_mps": [0.0, 0.0, 0.0]}]}
    t_reach = seconds_until_beyond([0, 0.5, 1.0], [0, 0.2, 0], SHOULDER_B_M, HOLD_RADIUS_M)
    t_s, where = course_exit(state, cfg, 1, np.array([0.0, 0.2, 0.0]), 5.0)
    assert t_reach - COURSE_STEP_S < t_s <= t_reach + COURSE_STEP_S
    assert where == f"out of floor's reach ({HOLD_RADIUS_M:g} m from its shoulder)"
    assert course_exit(state, cfg, 1, np.zeros(3), 5.0) == (np.inf, "")  # at rest: stays
    assert course_exit(state, cfg, 1, np.array([0.0, 0.2, 0.0]), 1.0)[0] == np.inf
    state["satellites"][0]["position_m"] = [0.0, 0.0, 0.3]  # near the floor of the box
    t_box = seconds_until_outside([0, 0, 0.3], [0, 0, -0.1], [-1.5, -1.5, 0.05],
                                  [1.5, 1.5, 2.4])
    t_s, where = course_exit(state, cfg, 1, np.array([0.0, 0.0, -0.1]), 5.0)
    assert (t_s, where) == (pytest.approx(t_box, abs=COURSE_STEP_S),
                            "out of floor's safety volume")
    state["satellites"][0]["position_m"] = [0.0, 0.5, 1.0]
    fast = load_scenario("gravity-stabilised")  # a time scale of 1000: 1.04 rad/s in the lab
    t_fast, where = course_exit(state, fast, 1, np.array([0.0, 0.2, 0.0]), 5.0)
    assert abs(t_fast - t_reach) > 0.1  # not the straight line's: z swings down to the floor
    assert where == "out of floor's safety volume"
    W = scaling_of(fast).orbit_rate_lab(orbit_rate(fast.orbit.altitude_m))
    for t, inside in ((t_fast - COURSE_STEP_S, True), (t_fast, False)):  # crossed there
        p = (cw_state_transition(W, t) @ np.array([0.0, 0.5, 1.0, 0.0, 0.2, 0.0]))[:3]
        assert (np.linalg.norm(p - SHOULDER_B_M) <= HOLD_RADIUS_M and p[2] >= 0.05) == inside


def test_on_a_rail_the_panel_measures_the_reach_from_the_rail_s_line():
    """A satellite drifting along the rail stays in reach (no warning, where the fixed arm's
    would warn); one drifting across it leaves the reach of the shoulder's line."""
    from app.backend.scene import course_warning
    from app.sim.ur10e import HOLD_RADIUS_M, SHOULDER_B_M

    def snap(velocity):
        return {"status": "running",
                "layout": {"T_W_R": np.eye(4).tolist(), "arms": [["floor", np.eye(4).tolist()]],
                           "rails_W_m": [[[0.0, -3.0, 0.0], [0.0, 3.0, 0.0]]],
                           "safety_boxes_W_m": [[[-5, -5, -5], [5, 5, 5]]]},
                "robots": [{"name": "floor", "satellite": 1}],
                "satellites": [{"position_W_m": [0.0, 0.5, 1.0], "velocity_mps": velocity}]}

    assert course_warning(snap([0.0, 0.2, 0.0])) == ""
    fixed = snap([0.0, 0.2, 0.0])
    del fixed["layout"]["rails_W_m"]
    assert "from its shoulder)" in course_warning(fixed)
    height = 1.0 - SHOULDER_B_M[2]
    t = np.sqrt(HOLD_RADIUS_M**2 - height**2) / 0.2  # across (x): 3.3 s
    text = course_warning(snap([0.2, 0.0, 0.0]))
    assert text.startswith(f"⚠ satellite 1 goes out of floor's reach ({HOLD_RADIUS_M:g} m "
                           f"from its shoulder's line along the rail) in ")
    assert float(text.split(" in ")[1].split(" s")[0]) == pytest.approx(t, abs=0.05)
