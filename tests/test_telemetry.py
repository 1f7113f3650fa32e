"""Telemetry (app/sim/telemetry.py): column layout, the recorder's row, the ring buffer."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.orbital import orbit_rate
from app.sim.rotations import (
    invert_transform,
    make_transform,
    matrix_to_quat,
    quat_to_matrix,
    rotvec_to_matrix,
    rotvec_to_quat,
)
from app.sim.telemetry import (
    GNC_FIELDS,
    ROBOT_FIELDS,
    SAT_FIELDS,
    Recorder,
    TelemetryBuffer,
    gnc_columns,
    loop_columns,
    robot_columns,
    satellite_columns,
    true_force_columns,
)

OMEGA = orbit_rate(800e3)


def test_loop_columns_are_time_satellites_arms_true_forces_gnc():
    cols = loop_columns(2, 3)
    assert len(cols) == len(set(cols)) == 1 + 2 * 19 + 3 * 28 + 2 * 3 + 2 * 6
    assert cols[0] == "t_s"
    assert cols[1:39] == satellite_columns(2)
    assert cols[39:123] == robot_columns(3)
    assert cols[123:129] == true_force_columns(2)
    assert cols[129:] == gnc_columns(2)
    assert cols[1:20] == [f"sat1_{f}" for f in SAT_FIELDS]
    assert cols[20] == "sat2_x_m" and cols[39] == "rob1_x_m" and cols[128] == "sat2_true_fz_N"
    assert cols[129:135] == [f"sat1_{f}" for f in GNC_FIELDS] and cols[-1] == "sat2_gnc_tz_Nm"
    assert ROBOT_FIELDS[10:16] == tuple(f"q{j}_rad" for j in range(1, 7))


@pytest.fixture(scope="module")
def recorded():
    """One row recorded from random but physical inputs: 2 satellites, 2 arms."""
    rng = np.random.default_rng(3)
    n_sat, n_arms = 2, 2
    T_W_R = make_transform(rotvec_to_matrix([0.3, -0.2, 0.9]), [-0.35, 0.1, 1.0])
    T_R_W = invert_transform(T_W_R)
    y = np.zeros((n_sat, 13))
    y[:, :6] = rng.normal(size=(n_sat, 6))
    y[:, 6:10] = [rotvec_to_quat(rng.normal(size=3)) for _ in range(n_sat)]
    y[0, 6:10] *= -1 if y[0, 6] > 0 else 1  # a quaternion with w < 0 is stored as it is
    y[:, 10:] = rng.normal(size=(n_sat, 3))
    force_R, torque_B, true_R = (rng.normal(size=(n_sat, 3)) for _ in range(3))
    arms = [(make_transform(rotvec_to_matrix(rng.normal(size=3)), rng.normal(size=3)),
             rng.normal(size=3), rng.normal(size=6), rng.normal(size=6), rng.normal(size=6))
            for _ in range(n_arms)]
    gnc = rng.normal(size=(n_sat, 6))
    rec = Recorder(n_sat, n_arms, 10, T_R_W, OMEGA)
    rec.record(12.5, y, force_R, torque_B, arms, true_R, gnc)
    row = dict(zip(rec.buffer.columns, rec.buffer.rows()[-1], strict=True))
    return row, {"T_R_W": T_R_W, "y": y, "force_R": force_R, "torque_B": torque_B,
                 "true_R": true_R, "arms": arms, "gnc": gnc}


def _vals(row, prefix, names):
    return np.array([row[f"{prefix}_{n}"] for n in names])


def test_recorder_row_satellite_columns(recorded):
    row, inp = recorded
    assert row["t_s"] == 12.5
    y = inp["y"]
    for i in range(2):
        s = f"sat{i + 1}"
        np.testing.assert_array_equal(_vals(row, s, ("x_m", "y_m", "z_m")), y[i, :3])
        np.testing.assert_array_equal(_vals(row, s, ("vx_mps", "vy_mps", "vz_mps")), y[i, 3:6])
        np.testing.assert_array_equal(_vals(row, s, ("qw", "qx", "qy", "qz")), y[i, 6:10])
        # angular velocity relative to R, body axes: ω − R_R_Bᵀ (Ω ẑ)
        w_rel = y[i, 10:] - quat_to_matrix(y[i, 6:10]).T @ [0.0, 0.0, OMEGA]
        np.testing.assert_allclose(_vals(row, s, ("wx_radps", "wy_radps", "wz_radps")),
                                   w_rel, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(_vals(row, s, ("fx_N", "fy_N", "fz_N")),
                                      inp["force_R"][i])
        np.testing.assert_array_equal(_vals(row, s, ("tx_Nm", "ty_Nm", "tz_Nm")),
                                      inp["torque_B"][i])
        np.testing.assert_array_equal(_vals(row, s, ("true_fx_N", "true_fy_N", "true_fz_N")),
                                      inp["true_R"][i])
        np.testing.assert_array_equal(_vals(row, s, GNC_FIELDS), inp["gnc"][i])


def test_recorder_row_arm_columns(recorded):
    row, inp = recorded
    T_R_W = inp["T_R_W"]
    for j, (T_W_C, v_W, q, raw_S, processed) in enumerate(inp["arms"]):
        r = f"rob{j + 1}"
        T_R_C = T_R_W @ T_W_C
        np.testing.assert_allclose(_vals(row, r, ("x_m", "y_m", "z_m")), T_R_C[:3, 3],
                                   rtol=0, atol=1e-14)
        quat = _vals(row, r, ("qw", "qx", "qy", "qz"))
        np.testing.assert_allclose(quat, matrix_to_quat(T_R_C[:3, :3]), rtol=0, atol=1e-14)
        np.testing.assert_allclose(quat_to_matrix(quat), T_R_C[:3, :3], atol=1e-14)
        np.testing.assert_allclose(_vals(row, r, ("vx_mps", "vy_mps", "vz_mps")),
                                   T_R_W[:3, :3] @ v_W, rtol=0, atol=1e-14)
        np.testing.assert_array_equal(_vals(row, r, [f"q{k}_rad" for k in range(1, 7)]), q)
        np.testing.assert_array_equal(
            _vals(row, r, ("ft_fx_N", "ft_fy_N", "ft_fz_N", "ft_tx_Nm", "ft_ty_Nm", "ft_tz_Nm")),
            raw_S)
        np.testing.assert_array_equal(
            _vals(row, r, ("pft_fx_N", "pft_fy_N", "pft_fz_N", "pft_tx_Nm", "pft_ty_Nm",
                           "pft_tz_Nm")), processed)


def test_recorder_without_arms_and_each_record_is_a_new_row():
    rec = Recorder(1, 0, 5, np.eye(4), OMEGA)
    y = np.zeros((1, 13))
    y[0, 6] = 1.0
    y[0, 12] = OMEGA  # at rest in R: inertial ω = Ω ẑ
    for k in range(3):
        rec.record(0.002 * k, y, np.full((1, 3), float(k)), np.zeros((1, 3)), [], np.zeros((1, 3)))
    rows = rec.buffer.rows()
    assert rows.shape == (3, len(loop_columns(1, 0)))
    np.testing.assert_array_equal(rows[:, 0], [0.0, 0.002, 0.004])
    np.testing.assert_array_equal(rec.buffer.column("sat1_fx_N"), [0.0, 1.0, 2.0])
    np.testing.assert_array_equal(rec.buffer.column("sat1_wz_radps"), 0.0)
    np.testing.assert_array_equal(rows[:, -6:], 0.0)  # no GNC: its columns are zeros


def test_recorder_refuses_a_state_of_the_wrong_shape_and_records_nothing():
    """The row kernels write without bounds checks: a wrong call must not reach them."""
    rec = Recorder(1, 0, 1, np.eye(4), OMEGA)
    y, z = np.zeros((1, 13)), np.zeros((1, 3))
    y[0, 6] = 1.0
    arm = (np.eye(4), np.zeros(3), np.zeros(6), np.zeros(6))
    for bad in ((np.zeros((2, 13)), z, z, [], z), (y, np.zeros((2, 3)), z, [], z),
                (y, z, z, [arm], z), (y, z, z, [], np.zeros((2, 3))),
                (y, z, z, [], z, np.zeros((1, 3)))):
        with pytest.raises(ValueError, match="recorder of 1 satellites and 0 arms"):
            rec.record(0.0, *bad)
    assert rec.buffer.count == 0


def test_recorder_refuses_an_array_of_another_dimension_and_records_nothing():
    """The row's kernel checks the shapes of 2-D arrays: a 1-D state must not get past it."""
    rec = Recorder(1, 0, 1, np.eye(4), OMEGA)
    z = np.zeros((1, 3))
    with pytest.raises(ValueError, match=r"recorder of 1 satellites and 0 arms got a state "
                                         r"\(13,\)"):
        rec.record(0.0, np.zeros(13), z, z, [], z)
    assert rec.buffer.count == 0


def test_rail_columns_come_last_and_only_for_the_robots_on_a_rail():
    assert loop_columns(2, 3, ()) == loop_columns(2, 3)  # no rail: the layout of before
    cols = loop_columns(2, 3, [1, 3])
    assert cols[:len(loop_columns(2, 3))] == loop_columns(2, 3)
    assert cols[len(loop_columns(2, 3)):] == [
        "rob1_rail_s_m", "rob1_rail_v_mps", "rob1_rail_sp_m",
        "rob3_rail_s_m", "rob3_rail_v_mps", "rob3_rail_sp_m"]


def test_recorder_writes_the_rails_after_the_gnc_and_refuses_a_missing_one():
    rec = Recorder(1, 0, 2, np.eye(4), OMEGA, rail_robots=[1])
    y, z = np.zeros((1, 13)), np.zeros((1, 3))
    y[0, 6] = 1.0
    gnc = np.arange(6.0).reshape(1, 6)
    rec.record(0.0, y, z, z, [], z, gnc, np.array([[0.5, -0.1, 0.52]]))
    row = rec.buffer.rows()[-1]
    np.testing.assert_array_equal(row[-9:-3], gnc.ravel())
    np.testing.assert_array_equal(row[-3:], [0.5, -0.1, 0.52])
    for rails in (None, np.zeros((2, 3))):
        with pytest.raises(ValueError, match=r"\(it has 1 rails\)"):
            rec.record(0.0, y, z, z, [], z, None, rails)
    assert rec.buffer.count == 1


# --- the ring buffer ---------------------------------------------------------------------------


def test_ring_buffer_keeps_the_newest_rows_oldest_first_and_counts_drops():
    buf = TelemetryBuffer(["a", "b"], capacity=3)
    assert buf.rows().shape == (0, 2) and buf.count == 0
    buf.append(np.array([0.0, 0.5]))
    buf.append(np.array([1.0, 1.5]))
    np.testing.assert_array_equal(buf.rows(), [[0, 0.5], [1, 1.5]])
    assert (buf.count, buf.dropped) == (2, 0)
    for k in range(2, 7):
        buf.append(np.array([k, k + 0.5]))
    assert (buf.count, buf.dropped, buf.capacity) == (3, 4, 3)
    np.testing.assert_array_equal(buf.rows(), [[4, 4.5], [5, 5.5], [6, 6.5]])
    np.testing.assert_array_equal(buf.rows(last=2), [[5, 5.5], [6, 6.5]])
    np.testing.assert_array_equal(buf.rows(last=10), buf.rows())
    np.testing.assert_array_equal(buf.column("b"), [4.5, 5.5, 6.5])
    np.testing.assert_array_equal(buf.column("a", last=1), [6.0])


def test_ring_buffer_rows_are_copies_and_next_row_writes_in_place():
    buf = TelemetryBuffer(["a", "b"], capacity=2)
    buf.next_row()[:] = [1.0, 2.0]
    snap = buf.rows()
    snap[0, 0] = 99.0
    np.testing.assert_array_equal(buf.rows(), [[1.0, 2.0]])  # a snapshot does not alias
    row = buf.next_row()
    assert buf.count == 2  # claimed counts as appended at once
    row[1] = 7.0
    np.testing.assert_array_equal(buf.rows()[-1], [0.0, 7.0])
    buf.next_row()[:] = [3.0, 4.0]  # overwrites the oldest
    assert buf.dropped == 1
    np.testing.assert_array_equal(buf.rows(), [[0.0, 7.0], [3.0, 4.0]])
    buf.clear()
    assert (buf.count, buf.dropped) == (0, 0) and buf.rows().shape == (0, 2)
    buf.append(np.array([5.0, 6.0]))
    np.testing.assert_array_equal(buf.rows(), [[5.0, 6.0]])


def test_ring_buffer_needs_room_for_a_row():
    with pytest.raises(ValueError, match="capacity must be at least 1"):
        TelemetryBuffer(["a"], capacity=0)


def test_a_ring_read_elsewhere_keeps_only_whole_rows():
    """ring_rows: a claimed row is not seen until committed; after a wrap the rows still
    whole are returned oldest first."""
    from app.sim.telemetry import ring_rows

    data, counters = np.zeros((3, 2)), np.zeros(2, dtype=np.int64)
    buf = TelemetryBuffer(["a", "b"], 3)
    buf.use_storage(data, counters)
    assert ring_rows(data, counters).shape == (0, 2)
    buf.append(np.array([0.0, 0.5]))
    row = buf.next_row()  # claimed, being written
    row[0] = 1.0
    np.testing.assert_array_equal(ring_rows(data, counters), [[0.0, 0.5]])
    buf.commit()
    np.testing.assert_array_equal(ring_rows(data, counters), [[0.0, 0.5], [1.0, 0.0]])
    for k in range(2, 6):
        buf.append(np.array([k, k + 0.5]))
    np.testing.assert_array_equal(ring_rows(data, counters), buf.rows())
    buf.next_row()  # claims the slot of the oldest row (3): it is no longer whole
    np.testing.assert_array_equal(ring_rows(data, counters), [[4, 4.5], [5, 5.5]])
    with pytest.raises(ValueError, match="already holds rows"):
        buf.use_storage(np.zeros((3, 2)), np.zeros(2, dtype=np.int64))


@pytest.mark.parametrize("n_arms", [1, 2, 3])
def test_a_row_with_arms_is_its_columns_written_one_call_each(n_arms):
    """The recorder writes a row with its first arms' columns in the row's own compiled
    call (one arm: record_row_arm; two: record_row_arms; more: the rest one call each):
    the same bits as record_row, then record_arm per arm."""
    from app.sim.telemetry import record_arm, record_row

    rng = np.random.default_rng(11)
    n_sat = 3
    T_R_W = invert_transform(make_transform(rotvec_to_matrix([0.2, 0.1, -0.4]),
                                            [0.1, -0.2, 0.9]))
    y = rng.normal(size=(n_sat, 13))
    y[:, 6:10] = [rotvec_to_quat(rng.normal(size=3)) for _ in range(n_sat)]
    force_R, torque_B, true_R = (rng.normal(size=(n_sat, 3)) for _ in range(3))
    gnc = rng.normal(size=(n_sat, 6))
    arms = [(make_transform(rotvec_to_matrix(rng.normal(size=3)), rng.normal(size=3)),
             rng.normal(size=3), rng.normal(size=6), rng.normal(size=6), rng.normal(size=6))
            for _ in range(n_arms)]
    rec = Recorder(n_sat, n_arms, 4, T_R_W, OMEGA)
    rec.record(0.5, y, force_R, torque_B, arms, true_R, gnc)
    staged = TelemetryBuffer(loop_columns(n_sat, n_arms), 4)
    at = record_row(0.5, y, OMEGA, force_R, torque_B, true_R, gnc, np.zeros((0, 3)), n_arms,
                    staged._data, staged._counters)
    k = 1 + len(SAT_FIELDS) * n_sat
    for arm in arms:
        k = record_arm(T_R_W, *arm, staged._data[at], k)
    staged.commit()
    assert rec.buffer.rows().tobytes() == staged.rows().tobytes()
