"""The web process's heavy reads (app/backend/service.py, app/backend/ring.py): the
telemetry ring read by file, whole or in chunks, and the shared, one-at-a-time
computation of metrics."""

from __future__ import annotations

import numpy as np
import pytest

from app.backend.service import SharedReads


def _ring_with_rows(n_rows: int, capacity: int = 100):
    """A run's ring (app/backend/ring.py) into which n_rows rows were written as the loop
    writes them (TelemetryBuffer over the shared storage), and the rows it must hold."""
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
    k = np.arange(n_rows, dtype=float)[:, None]
    written = 0.002 * k + np.arange(len(ring.columns)) / 7.0
    for row in written:
        buffer.append(row)
    del data, counters, buffer
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
        starts = sorted({first, *range((first // 7 + 1) * 7, n_rows, 7)}) if n_rows else []
        assert [f for f, _ in chunks] == starts  # whole chunks begin at multiples of 7
        assert all(len(c) <= 7 for _, c in chunks)
        joined = np.concatenate([c for _, c in chunks]) if chunks else rows[:0]
        assert np.array_equal(joined, expected)
    finally:
        ring.release()
    assert list(ring.chunks()) == []  # released: nothing to read, no error
    with pytest.raises(FileNotFoundError):
        ring.numbered_rows()


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
    cache.clear()
    assert cache.get("ring-b", 0) is None
