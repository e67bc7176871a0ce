"""Continuous collision detection (collide/ccd.py) and the rigid impact zones (collide/impact_zones.py)
on motions whose answer is known by construction."""
import numpy as np
import pytest
import taichi as ti

from taichi_sim.collide.ccd import (
    _segment_distance,
    edge_edge_hit,
    edge_edge_hit_between,
    point_triangle_distance,
    vertex_triangle_hit,
    vertex_triangle_hit_between,
)
from taichi_sim.collide.impact_zones import ImpactZones

DELTA = 1e-6
CASES = 400


def hits(kind, start, end, crossings_only=True):
    """(times, sides) of ``kind`` ('vt' or 'ee') for (m, 4, 3) start and end positions: vertex,
    then triangle (vt); edge a, then edge b (ee)."""
    m = len(start)
    x0 = ti.Vector.field(3, ti.f64, shape=(m, 4))
    x1 = ti.Vector.field(3, ti.f64, shape=(m, 4))
    out = ti.Vector.field(2, ti.f64, shape=m)
    x0.from_numpy(np.asarray(start, float))
    x1.from_numpy(np.asarray(end, float))

    @ti.kernel
    def run(only: ti.template()):
        for c in range(m):
            if ti.static(kind == "vt"):
                t, side = vertex_triangle_hit(x0[c, 0], x1[c, 0], x0[c, 1], x1[c, 1], x0[c, 2], x1[c, 2],
                                              x0[c, 3], x1[c, 3], DELTA, only)
                out[c] = ti.Vector([t, side])
            else:
                t, side = edge_edge_hit(x0[c, 0], x1[c, 0], x0[c, 1], x1[c, 1], x0[c, 2], x1[c, 2],
                                        x0[c, 3], x1[c, 3], DELTA, only)
                out[c] = ti.Vector([t, side])

    run(crossings_only)
    result = out.to_numpy()
    return result[:, 0], result[:, 1]


def volume(kind, x):
    """Six times the signed volume the cubic tracks, for (m, 4, 3) positions."""
    if kind == "vt":
        p, a, b, c = x[:, 0], x[:, 1], x[:, 2], x[:, 3]
        return np.einsum("ij,ij->i", np.cross(b - a, c - a), p - a)
    p, q, r, s = x[:, 0], x[:, 1], x[:, 2], x[:, 3]
    return np.einsum("ij,ij->i", np.cross(q - p, s - r), r - p)


def touching_motions(kind, rng, m):
    """Random linear motions that touch at a known time t*: a vertex inside the triangle, or the
    two edges crossing at interior points. Returns start, end (m, 4, 3) and t* (m,)."""
    t_star = rng.uniform(0.05, 0.95, m)
    at = rng.normal(size=(m, 4, 3))
    if kind == "vt":
        w = rng.dirichlet([2, 2, 2], m)  # interior barycentric weights
        at[:, 0] = np.einsum("ij,ijk->ik", w, at[:, 1:])
    else:
        u = rng.uniform(0.1, 0.9, (m, 2))
        meet = at[:, 0] + u[:, :1] * (at[:, 1] - at[:, 0])
        at[:, 2:] += (meet - (at[:, 2] + u[:, 1:] * (at[:, 3] - at[:, 2])))[:, None, :]
    # rotating-like motions: each corner its own velocity, large beside the primitives' size
    velocity = rng.normal(scale=2.0, size=(m, 4, 3))
    return at - t_star[:, None, None] * velocity, at + (1 - t_star)[:, None, None] * velocity, t_star


def separated_motions(kind, rng, m):
    """Random linear motions that never come within 0.1: the first primitive stays above y = 0.1,
    the second below y = 0 (each corner's straight path stays in its half-space)."""
    start, end = rng.normal(size=(m, 4, 3)), rng.normal(size=(m, 4, 3))
    first = slice(0, 1) if kind == "vt" else slice(0, 2)
    second = slice(1, 4) if kind == "vt" else slice(2, 4)
    for x in (start, end):
        x[:, first, 1] = 0.1 + np.abs(x[:, first, 1])
        x[:, second, 1] = -np.abs(x[:, second, 1])
    return start, end


@pytest.mark.parametrize("kind", ["vt", "ee"])
def test_every_touch_is_found_no_later_than_it_happens(f64, kind, rng):
    start, end, t_star = touching_motions(kind, rng, CASES)
    t_hit, _ = hits(kind, start, end)
    assert (t_hit >= 0).all()
    assert (t_hit <= t_star + 1e-9).all()
    # the motions include touches that the signs at the step's ends alone cannot see (the volume
    # changes sign twice, or not at all), the ones a start-and-end test misses
    same_sign = np.sign(volume(kind, start)) == np.sign(volume(kind, end))
    assert same_sign.sum() > 0.1 * CASES


@pytest.mark.parametrize("kind", ["vt", "ee"])
def test_apart_all_step_is_never_a_touch(f64, kind, rng):
    start, end = separated_motions(kind, rng, CASES)
    for crossings_only in (True, False):
        t_hit, _ = hits(kind, start, end, crossings_only)
        assert (t_hit < 0).all()


@pytest.mark.parametrize("kind", ["vt", "ee"])
def test_given_the_distances_the_tests_answer_the_same(f64, kind, rng):
    """The contact rounds pass the distances they computed (``*_hit_between``); the answers must
    be those of the tests that compute them, which reject a pair far apart at the start first."""
    cases = [touching_motions(kind, rng, CASES)[:2], separated_motions(kind, rng, CASES),
             (rng.normal(size=(CASES, 4, 3)), rng.normal(size=(CASES, 4, 3)))]
    start, end = (np.concatenate([case[k] for case in cases]) for k in (0, 1))
    m = len(start)
    x0 = ti.Vector.field(3, ti.f64, shape=(m, 4))
    x1 = ti.Vector.field(3, ti.f64, shape=(m, 4))
    out = ti.Vector.field(4, ti.f64, shape=m)
    x0.from_numpy(start)
    x1.from_numpy(end)

    @ti.kernel
    def run(only: ti.template()):
        for c in range(m):
            a0, a1, b0, b1, c0, c1, d0, d1 = x0[c, 0], x1[c, 0], x0[c, 1], x1[c, 1], x0[c, 2], x1[c, 2], x0[c, 3], x1[c, 3]
            if ti.static(kind == "vt"):
                t, side = vertex_triangle_hit(a0, a1, b0, b1, c0, c1, d0, d1, DELTA, only)
                u, other = vertex_triangle_hit_between(a0, a1, b0, b1, c0, c1, d0, d1, point_triangle_distance(a0, b0, c0, d0),
                                                       point_triangle_distance(a1, b1, c1, d1), DELTA, only)
                out[c] = ti.Vector([t, side, u, other])
            else:
                t, side = edge_edge_hit(a0, a1, b0, b1, c0, c1, d0, d1, DELTA, only)
                u, other = edge_edge_hit_between(a0, a1, b0, b1, c0, c1, d0, d1, _segment_distance(a0, b0, c0, d0),
                                                 _segment_distance(a1, b1, c1, d1), DELTA, only)
                out[c] = ti.Vector([t, side, u, other])

    for crossings_only in (True, False):
        run(crossings_only)
        result = out.to_numpy()
        # the same answer: touch or not, the same side, the same time up to round-off (the
        # compiler may fuse the cubic's products differently where the code is inlined)
        assert np.array_equal(result[:, 0] >= 0, result[:, 2] >= 0)
        assert np.array_equal(result[:, 1], result[:, 3])
        assert np.abs(result[:, 0] - result[:, 2]).max() < 1e-9
        assert (result[:CASES, 0] >= 0).all() and (result[CASES:2 * CASES, 0] < 0).all()  # both kinds met


def test_a_contact_that_ends_exactly_coplanar_is_a_touch_whatever_the_round_off(f32):
    # a triangle tilted at the start lands flat on y = 0 while a vertex lands on it there: f(1) is
    # exactly zero, and the cubic's coefficients summed in f32 need not give that zero's sign
    rng = np.random.default_rng(3)
    starts, ends = [], []
    for _ in range(64):
        tri1 = np.c_[rng.uniform(0, 1, 3), np.zeros(3), rng.uniform(0, 1, 3)]
        tri0 = tri1 + np.c_[np.zeros(3), rng.uniform(0, 0.01, 3), np.zeros(3)]
        p1 = tri1.mean(0)
        p0 = p1 + [0.0, 0.02, 0.0]
        starts.append([p0, *tri0])
        ends.append([p1, *tri1])
    t_hit, _ = hits("vt", np.array(starts), np.array(ends))
    assert (t_hit >= 0).all()


@pytest.mark.long
def test_the_side_is_the_one_before_the_touch(f64):
    # a vertex falling through a still triangle whose normal is +y: from above, then from below
    tri = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]
    start = np.array([[[0.2, 1.0, 0.2], *tri], [[0.2, -1.0, 0.2], *tri]])
    end = np.array([[[0.2, -1.0, 0.2], *tri], [[0.2, 1.0, 0.2], *tri]])
    t_hit, side = hits("vt", start, end)
    assert t_hit == pytest.approx([0.5, 0.5], abs=1e-9) and list(side) == [1.0, -1.0]
    # beside the triangle: no touch; resting on it from the start is no crossing, but is a touch
    beside = start + [[[2.0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]]]
    assert (hits("vt", beside, end + [[[2.0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]]])[0] < 0).all()
    resting = np.array([[[0.2, 0.0, 0.2], *tri]])
    assert hits("vt", resting, resting + [[[0, 1.0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]]])[0][0] < 0
    assert hits("vt", resting, resting + [[[0, 1.0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]]], False)[0][0] == 0.0


def rigid_zone_case(rng, n=12):
    mass = rng.uniform(0.5, 2.0, n)
    x0 = rng.normal(size=(n, 3))
    x1 = x0 + rng.normal(scale=0.3, size=(n, 3))
    v1 = rng.normal(size=(n, 3))  # end velocities need not be the displacement over the step
    return mass, x0, x1, v1


def test_a_zone_moves_rigidly_and_keeps_momentum_without_adding_energy(rng):
    mass, x0, x1, v1 = rigid_zone_case(rng)
    zones = ImpactZones(mass, np.ones(12, int))
    touches = np.array([[0, 1, 2, 3], [3, 4, 5, 6], [8, 9, 10, 11]])  # two zones: 0..6 and 8..11
    x_new, v_new = zones.rigidify(touches, x0, x1, v1, 0.1)
    assert x_new[7] == pytest.approx(x1[7]) and v_new[7] == pytest.approx(v1[7])  # in no zone
    for zone in (np.arange(7), np.arange(8, 12)):
        m = mass[zone, None]
        u_old, u_new = (x1[zone] - x0[zone]) / 0.1, (x_new[zone] - x0[zone]) / 0.1
        assert (m * v_new[zone]).sum(0) == pytest.approx((m * v1[zone]).sum(0))
        assert (m * u_new).sum(0) == pytest.approx((m * u_old).sum(0))
        c_new = (m * x_new[zone]).sum(0) / m.sum()
        # the velocities' rigid part at the new positions: their angular momentum is kept
        angular = (m * np.cross(x_new[zone] - c_new, v_new[zone])).sum(0)
        assert angular == pytest.approx((m * np.cross(x_new[zone] - c_new, v1[zone])).sum(0), rel=1e-9)
        assert (m * v_new[zone] ** 2).sum() <= (m * v1[zone] ** 2).sum()
        assert (m * u_new ** 2).sum() <= (m * u_old ** 2).sum() * (1 + 1e-12)
        # rigid: every distance inside the zone is kept
        d0 = np.linalg.norm(x0[zone, None] - x0[None, zone], axis=2)
        d1 = np.linalg.norm(x_new[zone, None] - x_new[None, zone], axis=2)
        assert d1 == pytest.approx(d0, abs=1e-12)


def test_a_zone_no_new_touch_reaches_keeps_its_motion(rng):
    mass, x0, x1, v1 = rigid_zone_case(rng)
    zones = ImpactZones(mass, np.ones(12, int))
    x_a, v_a = zones.rigidify(np.array([[0, 1, 2, 3]]), x0, x1, v1, 0.1)
    x_b, _ = zones.rigidify(np.array([[8, 9, 10, 11]]), x0, x_a, v_a, 0.1)
    assert np.array_equal(x_b[:4], x_a[:4])  # zone 0..3: no touch reached it, not moved again
    assert np.abs(x_b[8:] - x_a[8:]).max() > 1e-3  # zone 8..11 moved
    # why: fitting zone 0..3 again to its own rigid displacement is not the identity
    x_c, _ = zones.rigidify(np.array([[0, 1, 2, 3]]), x0, x_b, v_a, 0.1)
    assert np.abs(x_c[:4] - x_b[:4]).max() > 1e-3


def test_a_zone_that_gains_a_few_vertices_gives_them_its_motion_and_moves_no_other(rng):
    mass, x0, x1, v1 = rigid_zone_case(rng)
    zones = ImpactZones(mass, np.ones(12, int))
    x_a, v_a = zones.rigidify(np.array([[0, 1, 2, 3], [2, 3, 4, 5]]), x0, x1, v1, 0.1)  # zone 0..5
    x_b, v_b = zones.rigidify(np.array([[5, 6, 7, 0]]), x0, x_a, v_a, 0.1)  # gains 6 and 7
    assert np.array_equal(x_b[:6], x_a[:6])  # its vertices keep their places: their pairs need no new look
    zone = np.arange(8)
    d0 = np.linalg.norm(x0[zone, None] - x0[None, zone], axis=2)
    assert np.linalg.norm(x_b[zone, None] - x_b[None, zone], axis=2) == pytest.approx(d0, abs=1e-12)
    m = mass[zone, None]
    assert (m * v_b[zone]).sum(0) == pytest.approx((m * v_a[zone]).sum(0))  # momentum kept
    assert (m * v_b[zone] ** 2).sum() <= (m * v_a[zone] ** 2).sum() * (1 + 1e-12)  # no energy added
    assert np.array_equal(x_b[8:], x1[8:])
    # a zone whose earlier motion holds less than half of it is fitted again: every vertex moves
    zones = ImpactZones(mass, np.ones(12, int))
    x_a, v_a = zones.rigidify(np.array([[0, 1, 2, 3]]), x0, x1, v1, 0.1)
    x_c, _ = zones.rigidify(np.array([[4, 5, 6, 7], [8, 9, 10, 11], [7, 8, 3, 4]]), x0, x_a, v_a, 0.1)
    assert np.abs(x_c[:4] - x_a[:4]).max() > 1e-3
    d0 = np.linalg.norm(x0[:, None] - x0[None], axis=2)
    assert np.linalg.norm(x_c[:, None] - x_c[None], axis=2) == pytest.approx(d0, abs=1e-12)


def test_a_zone_turning_into_the_floor_stops_on_it_instead_of_being_lifted():
    # a flat strip on the floor whose right half rises: the fit tilts it, its left end into the floor
    n = 8
    mass = np.full(n, 0.01)
    x0 = np.stack([np.linspace(0.0, 0.2, n), np.full(n, 0.005), np.zeros(n)], axis=1)
    x1 = x0.copy()
    x1[n // 2:, 1] += 0.05
    v1 = (x1 - x0) / 0.1
    touches = np.array([[0, 1, 2, 3], [3, 4, 5, 6], [5, 6, 7, 0]])
    free_fit, _ = ImpactZones(mass, np.ones(n, int)).rigidify(touches, x0, x1, v1, 0.1)
    assert free_fit[:, 1].min() < -1e-3  # the whole fit ends its left end 1 cm deep
    x_new, _ = ImpactZones(mass, np.ones(n, int), floor=([0, 0, 0], [0, 1.0, 0])).rigidify(touches, x0, x1, v1, 0.1)
    assert x_new[:, 1].min() == pytest.approx(0.0, abs=1e-12)  # its lowest vertex on the floor
    d0 = np.linalg.norm(x0[:, None] - x0[None], axis=2)
    assert np.linalg.norm(x_new[:, None] - x_new[None], axis=2) == pytest.approx(d0, abs=1e-12)
    # cut short, not lifted: no vertex ends higher than the whole fit lifted onto the floor, and
    # the rising end ends lower (the lift raised every vertex by the left end's depth)
    lifted = free_fit[:, 1] - free_fit[:, 1].min()
    assert (x_new[:, 1] <= lifted + 1e-12).all() and x_new[:, 1].max() < lifted.max() - 1e-3


def test_a_zone_holding_a_pin_or_ending_in_the_floor_is_fitted_again_not_given_a_motion(rng):
    mass, x0, x1, v1 = rigid_zone_case(rng)
    free = np.ones(12, int)
    free[0] = 0  # a still pin
    x1[0] = x0[0]
    zones = ImpactZones(mass, free)
    x_a, v_a = zones.rigidify(np.array([[0, 1, 2, 3], [2, 3, 4, 5]]), x0, x1, v1, 0.1)
    x_b, _ = zones.rigidify(np.array([[5, 6, 7, 1]]), x0, x_a, v_a, 0.1)
    assert np.abs(x_b[1:6] - x_a[1:6]).max() > 1e-6  # fitted again with 6 and 7: its turn changed
    assert np.array_equal(x_b[0], x0[0])  # the pin stays
    # the motion of zone 0..5 would end 6 and 7 below the floor: the zone is fitted again and stops on it
    mass, x0, x1, v1 = rigid_zone_case(rng)
    x0[:, 1] = 10.0 + rng.uniform(0.0, 0.5, 12)
    x0[6:8, 1] = 9.0
    x1 = x0 + [0.0, -9.5, 0.0]
    zones = ImpactZones(mass, np.ones(12, int), floor=([0, 0, 0], [0, 1.0, 0]))
    x_a, v_a = zones.rigidify(np.array([[0, 1, 2, 3], [2, 3, 4, 5]]), x0, x1, v1, 0.1)
    assert x_a[:6, 1].min() > 0.0 and x1[6:8, 1].max() < 0.0
    x_b, _ = zones.rigidify(np.array([[5, 6, 7, 1]]), x0, x_a, v_a, 0.1)
    zone = np.arange(8)
    assert x_b[zone, 1].min() == pytest.approx(0.0, abs=1e-12)  # its lowest vertex on the floor
    d0 = np.linalg.norm(x0[zone, None] - x0[None, zone], axis=2)
    assert np.linalg.norm(x_b[zone, None] - x_b[None, zone], axis=2) == pytest.approx(d0, abs=1e-12)


def test_no_four_points_of_a_zone_become_coplanar_during_its_step(rng):
    mass, x0, x1, v1 = rigid_zone_case(rng)
    x_new, _ = ImpactZones(mass, np.ones(12, int)).rigidify(np.array([[0, 1, 2, 3], [2, 3, 4, 5]]), x0, x1, v1, 0.1)
    quads = np.array([[0, 1, 2, 3], [1, 3, 4, 5], [0, 2, 4, 5]])
    for t in np.linspace(0, 1, 101):
        x = x0 + t * (x_new - x0)
        assert (np.sign(volume("vt", x[quads])) == np.sign(volume("vt", x0[quads]))).all()


def test_a_zone_turns_about_its_still_pin_and_three_pins_hold_it_still(rng):
    mass, x0, x1, v1 = rigid_zone_case(rng)
    x1[:3] = x0[:3]  # particles 0, 1, 2 do not move
    free = np.ones(12, int)
    free[2] = 0
    x_new, _ = ImpactZones(mass, free).rigidify(np.array([[2, 3, 4, 5]]), x0, x1, v1, 0.1)
    assert (x_new[2] == x0[2]).all()
    reach0, reach1 = np.linalg.norm(x0[3:6] - x0[2], axis=1), np.linalg.norm(x_new[3:6] - x0[2], axis=1)
    assert reach1 == pytest.approx(reach0, rel=1e-6)  # a ball joint at the pin
    assert np.abs(x_new[3:6] - x0[3:6]).max() > 1e-3
    free[:3] = 0
    x_new, _ = ImpactZones(mass, free).rigidify(np.array([[0, 1, 2, 3], [2, 3, 4, 5]]), x0, x1, v1, 0.1)
    assert x_new[:6] == pytest.approx(x0[:6], abs=1e-6)


def test_a_zone_carries_its_pins_when_their_paths_keep_a_touch_inside_it(rng):
    mass, x0, x1, v1 = rigid_zone_case(rng)
    free = np.ones(12, int)
    free[:2] = 0  # two pins on paths no rigid motion follows: apart along x
    x1[0], x1[1] = x0[0] + [0.5, 0, 0], x0[1] - [0.5, 0, 0]
    zones = ImpactZones(mass, free)
    # one crossing found as several touches over the same vertices: not yet a touch inside a zone
    x_a, v_a = zones.rigidify(np.array([[0, 1, 2, 3], [0, 2, 1, 3], [1, 3, 0, 2]]), x0, x1, v1, 0.1)
    assert (x_a[:2] == x1[:2]).all()  # pins on their paths, so the zone cannot be rigid
    x_b, _ = zones.rigidify(np.array([[0, 1, 2, 3]]), x0, x_a, v_a, 0.1)  # the touch stayed inside
    d0 = np.linalg.norm(x0[:4, None] - x0[None, :4], axis=2)
    assert np.linalg.norm(x_b[:4, None] - x_b[None, :4], axis=2) == pytest.approx(d0, abs=1e-12)
    assert np.abs(x_b[:2] - x1[:2]).max() > 1e-3  # carried off their paths for this step


def test_a_zone_that_would_end_below_the_floor_is_moved_up_onto_it_rigidly(rng):
    mass, x0, x1, v1 = rigid_zone_case(rng)
    x0[:, 1] += 10.0  # all above the floor y = 0 at the start
    x1 = x0 + [0.0, -12.0, 0.0]  # falling through it
    zones = ImpactZones(mass, np.ones(12, int), floor=([0, 0, 0], [0, 1.0, 0]))
    x_new, _ = zones.rigidify(np.array([[0, 1, 2, 3]]), x0, x1, v1, 0.1)
    assert x_new[:4, 1].min() == pytest.approx(0.0, abs=1e-12)  # its lowest vertex on the floor
    d0 = np.linalg.norm(x0[:4, None] - x0[None, :4], axis=2)
    assert np.linalg.norm(x_new[:4, None] - x_new[None, :4], axis=2) == pytest.approx(d0, abs=1e-12)
    assert (x_new[4:] == x1[4:]).all()  # the floor is the plane collider's business elsewhere


def test_the_last_resort_moves_the_whole_cloth_as_one_rigid_zone(rng):
    mass, x0, x1, v1 = rigid_zone_case(rng)
    zones = ImpactZones(mass, np.ones(12, int))
    zones.merge_all()
    x_new, _ = zones.rigidify(np.zeros((0, 4), np.int64), x0, x1, v1, 0.1)
    d0 = np.linalg.norm(x0[:, None] - x0[None], axis=2)
    assert np.linalg.norm(x_new[:, None] - x_new[None], axis=2) == pytest.approx(d0, abs=1e-12)
