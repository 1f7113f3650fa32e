"""Box-box contact between mockups (DESIGN.md: contact between mockups, fidelity)."""

from __future__ import annotations

import coal
import numpy as np
import pytest

from app.config import DEFAULT_MATERIALS, ContactMaterial, SatelliteConfig
from app.sim.contact import (
    APART_GAP_M,
    APART_SLACK,
    BoxContactModel,
    boxes_apart,
    combine_materials,
    hunt_crossley_force,
)
from app.sim.rotations import make_transform, rotvec_to_matrix

SIZE = (0.2, 0.2, 0.1)
RIGID, SPONGE = DEFAULT_MATERIALS["rigid"], DEFAULT_MATERIALS["sponge"]
LOSSLESS = ContactMaterial(stiffness_Npm=2.0e4, damping_spm=0.0)


def _pose(p, rotvec=(0.0, 0.0, 0.0)):
    return make_transform(rotvec_to_matrix(rotvec), np.asarray(p, dtype=float))


def _pair(mat_a=RIGID, mat_b=SPONGE) -> BoxContactModel:
    return BoxContactModel([SIZE, SIZE], [mat_a, mat_b])


def _net_moment_about_origin(model, poses, wrench):
    return sum(wrench[i, 3:] + np.cross(poses[i][:3, 3], wrench[i, :3]) for i in range(model.n))


def test_series_stiffness_and_compliance_weighted_damping():
    k, c = combine_materials(RIGID, SPONGE)
    ka, kb = RIGID.stiffness_Npm, SPONGE.stiffness_Npm
    ca, cb = RIGID.damping_spm, SPONGE.damping_spm
    assert k == pytest.approx(ka * kb / (ka + kb))
    assert c == pytest.approx((ca / ka + cb / kb) / (1 / ka + 1 / kb))
    assert combine_materials(SPONGE, SPONGE) == pytest.approx((kb / 2, cb))


def test_boxes_apart_exert_nothing():
    model = _pair()
    for x in (0.21, 0.5):  # inside the bounding spheres' reach (coal runs), and beyond
        res = model.compute([_pose([0, 0, 0]), _pose([x, 0.0, 0.0])])
        assert not res.wrench_W.any() and res.contacts == ()


def test_overlapping_is_whether_compute_reports_a_contact():
    """overlapping (the ideal run's check after each step) answers as compute would:
    apart beyond the spheres, apart within them (coal asked), overlapping turned, and a
    pair no longer in the model."""
    model = BoxContactModel([SIZE, SIZE, SIZE], [RIGID, SPONGE, RIGID])
    cases = [
        [_pose([0, 0, 0]), _pose([0.5, 0, 0]), _pose([0, 0.5, 0])],
        [_pose([0, 0, 0]), _pose([0.205, 0.01, 0]), _pose([0, 0.5, 0])],
        [_pose([0, 0, 0]), _pose([0.19, 0.02, 0.01], (0.1, 0.0, 0.2)), _pose([0, 0.5, 0])],
        [_pose([0, 0, 0]), _pose([0.5, 0, 0]), _pose([0.01, 0.0, 0.095], (0.0, 0.3, 0.0))],
    ]
    answers = []
    for poses in cases:
        answers.append(model.overlapping(poses))
        assert answers[-1] == bool(model.compute(poses).contacts)
    assert answers == [False, False, True, True]
    model.exclude(0, 2)
    assert not model.overlapping(cases[3]) and not model.compute(cases[3]).contacts


def test_axis_aligned_overlap_depth_normal_point_and_force():
    model = _pair()
    poses = [_pose([0.0, 0.0, 0.0]), _pose([0.19, 0.05, 0.02])]
    res = model.compute(poses)
    (c,) = res.contacts
    assert c.geometry.depth_m == pytest.approx(0.01, rel=1e-6)
    np.testing.assert_allclose(c.geometry.normal_W, [1.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(c.geometry.point_W_m, [0.095, 0.025, 0.01], atol=1e-6)
    k_eff, _ = combine_materials(RIGID, SPONGE)
    np.testing.assert_allclose(res.wrench_W[1, :3], [k_eff * 0.01, 0, 0], rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(res.wrench_W[0, :3], -res.wrench_W[1, :3])
    # moments about each COM of the same contact force; net moment vanishes
    r_a = c.geometry.point_W_m - poses[0][:3, 3]
    np.testing.assert_allclose(res.wrench_W[0, 3:], np.cross(r_a, res.wrench_W[0, :3]))
    # contact 25 mm off the x-axis: a real moment about z
    assert res.wrench_W[0, 5] == pytest.approx(0.025 * k_eff * 0.01, rel=1e-6)
    np.testing.assert_allclose(_net_moment_about_origin(model, poses, res.wrench_W), 0, atol=1e-12)


def test_approach_speed_adds_damping_and_separation_never_pulls():
    model = _pair()
    poses = [_pose([0.0, 0.0, 0.0]), _pose([0.195, 0.0, 0.0])]  # 5 mm deep
    k, c = model.law(0, 1)
    approaching = model.compute(poses, v_W_mps=[[0.1, 0, 0], [-0.1, 0, 0]])
    assert approaching.contacts[0].depth_rate_mps == pytest.approx(0.2)
    assert approaching.wrench_W[1, 0] == pytest.approx(k * 0.005 * (1 + c * 0.2), rel=1e-6)
    separating = model.compute(poses, v_W_mps=[[0.0, 0, 0], [1.0, 0, 0]])  # 1 + c ḋ < 0
    assert separating.contacts[0].normal_force_N == 0.0
    assert not separating.wrench_W.any()
    assert hunt_crossley_force(0.005, -1.0, k, c) == 0.0
    assert hunt_crossley_force(-0.001, 1.0, k, c) == 0.0


def test_spin_contributes_to_depth_rate_at_the_contact_point():
    model = _pair()
    poses = [_pose([0.0, 0.0, 0.0]), _pose([0.195, 0.06, 0.0])]
    res = model.compute(poses, omega_W_radps=[[0, 0, -2.0], [0, 0, 0]])
    p = res.contacts[0].geometry.point_W_m
    assert res.contacts[0].depth_rate_mps == pytest.approx(np.cross([0, 0, -2.0], p)[0])


def test_rotated_box_gives_face_normal_and_corner_depth():
    model = _pair()
    poses = [_pose([0.0, 0.0, 0.0]), _pose([0.2, 0.0, 0.0], [0.0, 0.0, np.pi / 4])]
    (c,) = model.compute(poses).contacts
    assert c.geometry.depth_m == pytest.approx(0.1 + 0.1 * np.sqrt(2) - 0.2, rel=1e-6)
    np.testing.assert_allclose(c.geometry.normal_W, [1.0, 0.0, 0.0], atol=1e-6)
    assert 0.05 < c.geometry.point_W_m[0] < 0.1 and abs(c.geometry.point_W_m[1]) < 1e-6
    # the same boxes the other way round: the normal flips (still from a towards b)
    swapped = model.compute([poses[1], poses[0]]).contacts[0]
    np.testing.assert_allclose(swapped.geometry.normal_W, [-1.0, 0.0, 0.0], atol=1e-6)


def test_three_bodies_all_pairs():
    sats = [SatelliteConfig(name=f"s{i}", material=m) for i, m in enumerate(["rigid"] * 3)]
    model = BoxContactModel.from_satellites(sats)
    poses = [_pose([0.0, 0, 0]), _pose([0.19, 0, 0]), _pose([0.38, 0, 0])]
    res = model.compute(poses)
    assert sorted((c.a, c.b) for c in res.contacts) == [(0, 1), (1, 2)]
    np.testing.assert_allclose(res.wrench_W[1, :3], 0.0, atol=1e-6)  # squeezed both ways
    np.testing.assert_allclose(res.wrench_W.sum(axis=0)[:3], 0.0, atol=1e-12)


def _collide_1d(mat_a: ContactMaterial, mat_b: ContactMaterial, dt=1.0 / 500.0, steps=750):
    """Head-on collision along x, integrated with semi-implicit Euler and no delay."""
    model = _pair(mat_a, mat_b)
    m = np.array([1.0, 1.5])
    x = np.array([0.0, 0.25])
    v = np.array([0.1, -0.1])
    impulse = np.zeros((2, 3))
    peak_depth = 0.0
    for _ in range(steps):
        poses = [_pose([x[0], 0, 0]), _pose([x[1], 0, 0])]
        vel = np.array([[v[0], 0, 0], [v[1], 0, 0]])
        res = model.compute(poses, v_W_mps=vel)
        for c in res.contacts:
            peak_depth = max(peak_depth, c.geometry.depth_m)
        impulse += res.wrench_W[:, :3] * dt
        v = v + res.wrench_W[:, 0] / m * dt
        x = x + v * dt
    return m, np.array([0.1, -0.1]), v, impulse, peak_depth


@pytest.mark.parametrize(
    ("mat_a", "mat_b", "e_lo", "e_hi"),
    [
        (RIGID, SPONGE, 0.0, 0.7),  # the paper's scenario: soft, lossy -> inelastic
        (LOSSLESS, LOSSLESS, 0.97, 1.03),  # undamped springs: (nearly) elastic
    ],
)
def test_two_body_collision_momentum_impulse_and_restitution(mat_a, mat_b, e_lo, e_hi):
    m, v0, v1, impulse, peak_depth = _collide_1d(mat_a, mat_b)
    assert peak_depth > 0.0 and v1[0] < v1[1]  # they touched and now separate
    p0, p1 = m @ v0, m @ v1
    assert abs(p1 - p0) <= 1e-12 * np.abs(m * v0).sum()
    np.testing.assert_array_equal(impulse[0], -impulse[1])
    assert impulse[1, 0] > 0.0
    np.testing.assert_allclose(m * (v1 - v0), impulse[:, 0], rtol=1e-9)
    e = (v1[1] - v1[0]) / (v0[0] - v0[1])
    assert e_lo < e < e_hi


def test_an_undamped_hertz_impact_is_elastic_and_lasts_its_closed_form():
    """F = k d^1.5 without damping (Hertz): the ideal collision returns the satellites at
    their approach speed (e = 1) after the closed-form duration of a Hertz impact,
    T = 2.9432 δ_max / v₀ with δ_max = (5 m v₀² / (4 k))^(2/5), m the reduced mass
    (Johnson, Contact Mechanics §11.4); the linear law's would be π sqrt(m / k), 40 ms."""
    from app.config import merge_overrides
    from app.runs.headless import ideal_collision
    from app.scenarios import load_scenario

    hertz = {"stiffness_Npm": 6300.0, "damping_spm": 0.0, "exponent": 1.5}
    config = merge_overrides(load_scenario("collision"),
                             {"materials": {"sponge": hertz, "rigid": hertz}})
    coll = ideal_collision(config, 4.0)
    k = 6300.0 / 2.0  # two equal surfaces in series
    v0 = coll["approach_speed_mps"]
    t_exact = 2.9432 * (5.0 * 0.5 * v0**2 / (4.0 * k)) ** 0.4 / v0
    assert coll["restitution"] == pytest.approx(1.0, abs=2e-3)
    assert coll["contact_duration_s"] == pytest.approx(t_exact, abs=0.003)
    assert hunt_crossley_force(0.004, 0.1, 6300.0, 2.0, 1.5) == pytest.approx(
        6300.0 * 0.004**1.5 * 1.2)


def test_mockups_built_larger_than_drawn_touch_earlier_and_the_lab_keeps_the_drawing():
    """Each mockup 2 mm larger than its drawing: the physics' boxes touch 2 mm of approach
    (2 mm / v₀) before the drawn ones would, while the lab's geometry stays the drawing."""
    from app.config import merge_overrides
    from app.runs.headless import ideal_collision
    from app.scenarios import load_scenario
    from app.sim.loop import Emulator

    base = load_scenario("collision")
    grown = merge_overrides(base, {"satellites": {"0": {"size_error_m": 0.002},
                                                  "1": {"size_error_m": 0.002}}})
    drawn, built = ideal_collision(base, 4.0), ideal_collision(grown, 4.0)
    early_s = drawn["contact_start_s"] - built["contact_start_s"]
    assert early_s == pytest.approx(0.002 / drawn["approach_speed_mps"], abs=0.002)
    em = Emulator(grown)
    assert em.interaction.contact._sizes_m[0] == pytest.approx((0.202, 0.202, 0.102))
    assert em.lab_geometry._sizes_m[0] == pytest.approx((0.2, 0.2, 0.1))
    assert Emulator(base).lab_geometry is not None


def _wrenches_by_arrays(model, T_W_C, v, w):
    """The contact wrenches with every step an array operation (Eq. HC, Coulomb, equal
    and opposite at the point): what compute's plain-float arithmetic must give bit for
    bit."""
    from app.sim.contact import coulomb_friction

    wrench = np.zeros((model.n, 6))
    for c in model.compute(T_W_C, v, w).contacts:  # its geometry: coal's, not re-derived
        a, b, geo = c.a, c.b, c.geometry
        p, n = geo.point_W_m, geo.normal_W
        r_a, r_b = p - T_W_C[a][:3, 3], p - T_W_C[b][:3, 3]
        cross = lambda x, y: np.array([x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2],  # noqa: E731
                                       x[0] * y[1] - x[1] * y[0]])
        v_rel = (v[a] + cross(w[a], r_a)) - (v[b] + cross(w[b], r_b))
        depth_rate = float(v_rel @ n)
        assert depth_rate == c.depth_rate_mps
        f_n = hunt_crossley_force(geo.depth_m, depth_rate, *model.law(a, b),
                                  model._exponent[(a, b)])
        assert f_n == c.normal_force_N
        mu = model.friction(a, b)
        friction = None if mu == 0.0 else coulomb_friction(f_n, v_rel - depth_rate * n, mu)
        if f_n == 0.0:
            continue
        f_b = f_n * n if friction is None else f_n * n + friction
        wrench[b, :3] += f_b
        wrench[a, :3] -= f_b
        wrench[b, 3:] += cross(r_b, f_b)
        wrench[a, 3:] -= cross(r_a, f_b)
    return wrench


@pytest.mark.parametrize("friction", [0.0, 0.5])
def test_compute_gives_the_array_arithmetic_bit_for_bit(friction):
    """Three bodies in random overlapping poses, velocities and spins (with and without
    friction): the wrenches are the array formulas' to the last bit, -0.0 included."""
    material = ContactMaterial(stiffness_Npm=8000.0, damping_spm=5.0, friction=friction)
    model = BoxContactModel([SIZE] * 3, [material] * 3)
    rng = np.random.default_rng(33)
    touched = 0
    for _ in range(300):
        T_W_C = np.array([_pose(rng.normal(0.0, 0.08, 3) + [0.17 * i, 0, 0],
                                rng.normal(0.0, 0.3, 3)) for i in range(3)])
        v, w = rng.normal(0.0, 0.1, (3, 3)), rng.normal(0.0, 0.5, (3, 3))
        v[0, 2] = 0.0  # zeros too: the sign of a zero sum must come out the same
        got = model.compute(T_W_C, v, w)
        touched += len(got.contacts)
        assert got.wrench_W.tobytes() == _wrenches_by_arrays(model, T_W_C, v, w).tobytes()
    assert touched > 100


def test_clearance_frames_are_the_array_formulas_on_coal_s_own_answer():
    """The contact frames of clearances() (poses handed to coal as C-ordered copies, the
    frame's sums on floats) are, bit for bit, the array formulas on coal's answer for the
    poses handed over as views of the 4 × 4 matrices."""
    import coal

    model = BoxContactModel([SIZE] * 3, [RIGID] * 3)
    shapes = [coal.Box(*SIZE) for _ in range(3)]
    rng = np.random.default_rng(5)
    framed = 0
    for _ in range(200):
        T_W_C = np.array([_pose(rng.normal(0.0, 0.06, 3) + [0.19 * i, 0, 0],
                                rng.normal(0.0, 0.3, 3)) for i in range(3)])
        model.frames.clear()
        clearance, _, _ = model.clearances(T_W_C, 0.02)
        for (a, b), (normal, point) in model.frames.items():
            tf = [coal.Transform3s() for _ in range(2)]
            for t, i in zip(tf, (a, b), strict=True):
                t.setRotation(T_W_C[i][:3, :3])
                t.setTranslation(T_W_C[i][:3, 3])
            res = coal.DistanceResult()
            d = coal.ComputeDistance(shapes[a], shapes[b])(tf[0], tf[1],
                                                           coal.DistanceRequest(), res)
            n = np.array(res.normal, dtype=float)
            on_plane = 0.5 * (res.getNearestPoint1() + res.getNearestPoint2())
            mid = 0.5 * (T_W_C[a][:3, 3] + T_W_C[b][:3, 3])
            assert normal.tobytes() == n.tobytes()
            assert point.tobytes() == (mid + float((on_plane - mid) @ n) * n).tobytes()
            assert min(clearance[a], clearance[b]) <= d
            framed += 1
    assert framed > 100


def _spheres_apart(model: BoxContactModel, poses: np.ndarray, within_m: float) -> bool:
    """apart()'s bounding-sphere test alone (its face test off: no gap exceeds inf)."""
    return boxes_apart(poses, model._pair_index, model._half_m, model._radii_m, within_m,
                       1.0 + APART_SLACK, np.inf)


def test_apart_by_the_bounding_spheres_only_where_every_arrays_test_skips_its_pair():
    """Centre distances at the bounding spheres' reach (+ a margin) and a few ulps either
    side, and clearly beyond: where apart()'s sphere test holds, the arrays' test of
    geometry() and clearances() skips the pair (compute and clearances report nothing);
    next to the boundary it leaves the decision to them."""
    model = _pair()
    reach = 2 * 0.5 * float(np.sqrt(sum(x * x for x in SIZE)))
    rng = np.random.default_rng(3)
    for within_m in (0.0, 0.001):
        boundary = reach + within_m
        for scale in [1.0 + k * 2.2e-16 for k in range(-8, 9)] + [1.0 + 1e-8, 1.5]:
            direction = rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            poses = np.array([_pose([0.1, -0.2, 0.3]),
                              _pose(np.array([0.1, -0.2, 0.3]) + boundary * scale * direction,
                                    rng.normal(0.0, 0.3, 3))])
            d_ab = poses[1][:3, 3] - poses[0][:3, 3]
            arrays_skip = float(d_ab.dot(d_ab)) > boundary * boundary
            if _spheres_apart(model, poses, within_m):
                assert arrays_skip and scale > 1.0 + 1e-12
                assert model.apart(poses, within_m)
                assert model.compute(poses).contacts == ()
                clearance, nearest, crowd = model.clearances(poses, within_m)
                assert np.isinf(clearance).all() and (nearest == -1).all() and not crowd.any()
            else:
                assert scale < 1.0 + 1e-12
    assert model.apart(np.array([_pose([0, 0, 0]), _pose([1.0, 0, 0])]))
    assert not model.apart(np.array([_pose([0, 0, 0]), _pose([0.1, 0, 0])]))
    assert BoxContactModel([SIZE], [RIGID]).apart(np.array([_pose([0, 0, 0])]))
    # a pose gone NaN is no free flight: the arrays' test, which does not skip it, decides
    assert not model.apart(np.array([_pose([0, 0, 0]), _pose([np.nan, 0, 0])]))
    assert not model.apart(np.array([_pose([0, 0, 0]), _pose([0.25, 0, 0], [np.nan, 0, 0])]))


def test_apart_by_a_face_only_where_coal_finds_the_boxes_apart():
    """Boxes of other sizes, turned at random, their bounding spheres overlapping, from
    touching to a few cm apart: wherever apart() holds, coal's distance is more than
    within_m and compute and clearances report nothing; face to face it holds from
    within_m + APART_GAP_M on, not before."""
    sizes = [(0.2, 0.2, 0.1), (0.3, 0.15, 0.25)]
    model = BoxContactModel(sizes, [RIGID, SPONGE])
    shape = [coal.Box(*s) for s in sizes]
    solver, request = coal.ComputeDistance(*shape), coal.DistanceRequest()
    rng = np.random.default_rng(11)
    by_face = 0
    for k in range(3000):
        within_m = (0.0, 0.001)[k % 2]
        poses = np.array([_pose(rng.normal(0.0, 0.1, 3), rng.normal(0.0, 1.0, 3)),
                          _pose(rng.normal(0.0, 0.2, 3), rng.normal(0.0, 1.0, 3))])
        tf = [coal.Transform3s(T[:3, :3], T[:3, 3]) for T in poses]
        distance_m = solver(tf[0], tf[1], request, coal.DistanceResult())
        if _spheres_apart(model, poses, within_m) or not model.apart(poses, within_m):
            continue
        by_face += 1
        assert distance_m > within_m + 0.5 * APART_GAP_M, (k, distance_m)
        assert model.compute(poses).contacts == ()
        clearance, nearest, crowd = model.clearances(poses, within_m)
        assert np.isinf(clearance).all() and (nearest == -1).all() and not crowd.any()
    assert by_face > 300
    thin = 0.5 * (sizes[0][2] + sizes[1][2])  # face to face along z, the spheres overlapping
    for within_m in (0.0, 0.001):
        edge = thin + within_m + APART_GAP_M
        for gap, expected in ((-1e-9, False), (1e-9, True)):
            poses = np.array([_pose([0.0, 0.0, 0.0]), _pose([0.02, -0.01, edge + gap])])
            assert not _spheres_apart(model, poses, within_m)
            assert model.apart(poses, within_m) is expected


def test_apart_refuses_poses_of_another_shape_and_follows_new_pairs():
    """Fewer poses than bodies, or poses that are not 4 x 4: a ValueError (the arrays'
    indexing raised before), not an answer read from outside the array; (N, 3, 4) poses
    answer as their (N, 4, 4); pairs set anew are the ones apart() tests."""
    model = BoxContactModel([SIZE] * 3, [RIGID] * 3)
    poses = np.array([_pose([0, 0, 0]), _pose([1.0, 0, 0]), _pose([0, 1.0, 0])])
    for bad in (poses[:2], poses[:, :3, :3].copy(), poses[:, :, :3].copy()):
        with pytest.raises(ValueError, match="one \\(4, 4\\) per body"):
            model.apart(bad)
    assert model.apart(poses[:, :3, :].copy()) is model.apart(poses) is True
    near = poses.copy()
    near[1, 0, 3] = 0.15  # bodies 0 and 1 overlap
    assert not model.apart(near)
    model.exclude(0, 1)
    assert model.apart(near) and model.compute(near).contacts == ()
    model.pairs = [(0, 1), (0, 2), (1, 2)]
    assert not model.apart(near) and len(model.compute(near).contacts) == 1
