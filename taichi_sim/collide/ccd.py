"""Continuous collision detection: when, within a step, a vertex meets a triangle or an edge an edge.

Every vertex moves on a straight line from its start to its end position during the step
(t in [0, 1]). Four points can only touch when they are coplanar, and the volume they span,
f(t) = (b(t) x c(t)) . p(t) with b, c, p measured from the fourth point, is a cubic in t (Provot
1997; Bridson, Fedkiw and Anderson 2002). Its roots in [0, 1] are found on the (at most three)
pieces where it is monotone, by bisection, which cannot miss a sign change the way Newton's method
can; the critical points themselves are kept as candidates, so a grazing touch (a double root,
no sign change) is tested too. At each candidate time the primitives' true distance decides: a
collision is a candidate time at which they are closer than ``delta``. Round-off can shift a root
but not remove a sign change, and the distance test with ``delta`` (a small fraction of the
cloth thickness) absorbs the shift, so a crossing is reported rather than missed.
"""
import taichi as ti

from .closest_points import closest_barycentric, segment_parameters

# the root's time to 2^-40 of the step (far below any distance that matters), or as close as the
# precision allows: in f32 no float is left between the ends after about 24 halvings for a root
# near the end of the step (more for one near its start, where floats are denser)
BISECTIONS = 40
NO_TIME = -1.0  # a candidate or collision time that does not exist


@ti.func
def coplanarity_cubic(b0, db, c0, dc, p0, dp):
    """Coefficients (k0, k1, k2, k3) of f(t) = (b(t) x c(t)) . p(t) = k0 + k1 t + k2 t^2 + k3 t^3,
    where b(t) = b0 + t db, and so on: six times the signed volume of the tetrahedron."""
    x0 = b0.cross(c0)
    x1 = db.cross(c0) + b0.cross(dc)
    x2 = db.cross(dc)
    return ti.Vector([x0.dot(p0), x1.dot(p0) + x0.dot(dp), x2.dot(p0) + x1.dot(dp), x2.dot(dp)])


@ti.func
def cubic_at(k, t):
    return ((k[3] * t + k[2]) * t + k[1]) * t + k[0]


@ti.func
def _critical_points(k):
    """The roots of f'(t) = 3 k3 t^2 + 2 k2 t + k1, sorted; 2.0 (outside [0, 1]) where none."""
    a, b, c = 3.0 * k[3], 2.0 * k[2], k[1]
    r1, r2 = 2.0, 2.0
    if a != 0.0:
        disc = b * b - 4.0 * a * c
        if disc >= 0.0:
            root = ti.sqrt(disc)
            q = -0.5 * (b + root) if b >= 0.0 else -0.5 * (b - root)
            if q != 0.0:
                r1, r2 = q / a, c / q  # the stable pair of quadratic roots
            else:
                r1, r2 = 0.0, 0.0
    elif b != 0.0:
        r1 = -c / b
    if r2 < r1:
        r1, r2 = r2, r1
    return r1, r2


@ti.func
def _bisect(k, lo, hi):
    f_lo = cubic_at(k, lo)
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:  # the interval is down to two neighbouring floats
            break
        f_mid = cubic_at(k, mid)
        if (f_mid < 0.0) == (f_lo < 0.0) and f_mid != 0.0:
            lo, f_lo = mid, f_mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@ti.func
def candidate_times(k, crossings_only: ti.template()):
    """Times in [0, 1] at which f may vanish or come nearest to it: its roots (one per monotone
    piece with a sign change) and its interior critical points; NO_TIME fills unused entries.

    With ``crossings_only``, only the times at which f changes sign or reaches zero, not the
    critical points and not a zero it starts from: the moments the primitives could pass through
    each other, rather than all the moments they come near; and the end of the step, because a
    contact that ends exactly coplanar (two layers laid on one plane) has its zero at t = 1, where
    round-off can give f the sign it started with and hide it."""
    r1, r2 = _critical_points(k)
    in1, in2 = r1 > 0.0 and r1 < 1.0, r2 > 0.0 and r2 < 1.0
    times = ti.Vector([NO_TIME, NO_TIME, NO_TIME, NO_TIME, NO_TIME])
    knots = ti.Vector([0.0, 1.0, 1.0, 1.0])  # the monotone pieces: [knots[j], knots[j + 1]]
    if in1 and in2:
        knots[1], knots[2] = r1, r2
    elif in1:
        knots[1] = r1
    elif in2:
        knots[1] = r2
    start_counts = 1  # a zero at t = 0 is a candidate
    if ti.static(not crossings_only):
        if in1:
            times[3] = r1
        if in2:
            times[4] = r2
    else:
        start_counts = 0
        times[3] = 1.0
    # runtime loops, here and over the candidates: unrolled, each inlined its bisection or
    # distance test again, and compiling the stage took seconds longer
    for j in range(3):
        lo, hi = knots[j], knots[j + 1]
        if j == 0 or hi > lo:
            f_lo, f_hi = cubic_at(k, lo), cubic_at(k, hi)
            if f_lo == 0.0:
                if start_counts == 1 or j > 0:
                    times[j] = lo
            elif f_hi == 0.0:
                times[j] = hi
            elif (f_lo < 0.0) != (f_hi < 0.0):
                times[j] = _bisect(k, lo, hi)
    return times


@ti.func
def _side_before(k, t_hit):
    """Which side (+1 or -1) of the plane the tetrahedron's volume says the primitives were on
    before they met at ``t_hit``: its sign halfway there (+1 when the motion stayed coplanar)."""
    f = cubic_at(k, 0.5 * t_hit)
    if f == 0.0:
        f = k[0]
    return -1.0 if f < 0.0 else 1.0


@ti.func
def _counts(t, start_distance, delta, crossings_only: ti.template()):
    """Whether candidate time ``t`` is tested: with ``crossings_only``, the step's end only for a
    pair that did not start within ``delta`` (no rigid motion can part such a pair, so it would
    keep the fail-safe's zones from ever finishing)."""
    ok = True
    if ti.static(crossings_only):
        ok = t < 1.0 or start_distance >= delta
    return ok


@ti.func
def _motion_spread(d0, d1, d2, d3):
    """How far any point of one primitive can move relative to any point of the other during the
    step, given the four corners' displacements: their spread about a common translation."""
    mean = 0.25 * (d0 + d1 + d2 + d3)
    return 2.0 * ti.max(ti.max((d0 - mean).norm(), (d1 - mean).norm()),
                        ti.max((d2 - mean).norm(), (d3 - mean).norm()))


@ti.func
def point_triangle_distance(p, a, b, c):
    w = closest_barycentric(p, a, b, c)
    return (p - (w[0] * a + w[1] * b + w[2] * c)).norm()


@ti.func
def _segment_distance(p, q, r, s):
    u = segment_parameters(p, q, r, s)
    return ((p + u[0] * (q - p)) - (r + u[1] * (s - r))).norm()


@ti.func
def vertex_triangle_hit(p0, p1, a0, a1, b0, b1, c0, c1, delta, crossings_only: ti.template()):
    """The earliest time in [0, 1] at which vertex p comes within ``delta`` (m) of triangle (a, b, c),
    all moving linearly from their ``0`` to their ``1`` positions, or NO_TIME; and the side
    (+1: the direction of (b - a) x (c - a)) p was on before. ``crossings_only``: see
    :func:`candidate_times`."""
    spread = _motion_spread(p1 - p0, a1 - a0, b1 - b0, c1 - c0)
    start = point_triangle_distance(p0, a0, b0, c0)
    t_hit, side = NO_TIME, 1.0
    if start - spread <= 2.0 * delta:  # else too far apart at the start to touch, whatever the end
        t_hit, side = _vertex_triangle_hit(p0, p1, a0, a1, b0, b1, c0, c1, start,
                                           point_triangle_distance(p1, a1, b1, c1), spread, delta, crossings_only)
    return t_hit, side


@ti.func
def vertex_triangle_hit_between(p0, p1, a0, a1, b0, b1, c0, c1, start, end, delta, crossings_only: ti.template()):
    """:func:`vertex_triangle_hit` for a caller that has the vertex's distances (m) to the
    triangle at the step's ``start`` and ``end`` already."""
    return _vertex_triangle_hit(p0, p1, a0, a1, b0, b1, c0, c1, start, end,
                                _motion_spread(p1 - p0, a1 - a0, b1 - b0, c1 - c0), delta, crossings_only)


@ti.func
def _vertex_triangle_hit(p0, p1, a0, a1, b0, b1, c0, c1, start, end, spread, delta, crossings_only: ti.template()):
    t_hit, side = NO_TIME, 1.0
    # the distance can shrink no faster than the motion's spread: far apart at both ends
    # relative to it, the pair cannot touch in between (the common case, without the cubic)
    if start + end - spread <= 2.0 * delta:
        ea0, eb0, ep0 = b0 - a0, c0 - a0, p0 - a0
        k = coplanarity_cubic(ea0, (b1 - a1) - ea0, eb0, (c1 - a1) - eb0, ep0, (p1 - a1) - ep0)
        t_hit, side = _earliest_touch(k, p0, p1, a0, a1, b0, b1, c0, c1, start, delta, crossings_only, True)
    return t_hit, side


@ti.func
def edge_edge_hit(p0, p1, q0, q1, r0, r1, s0, s1, delta, crossings_only: ti.template()):
    """The earliest time in [0, 1] at which segments (p, q) and (r, s), moving linearly, come
    within ``delta`` (m), or NO_TIME; and the side (+1: r - p along (q - p) x (s - r)) before."""
    spread = _motion_spread(p1 - p0, q1 - q0, r1 - r0, s1 - s0)
    start = _segment_distance(p0, q0, r0, s0)
    t_hit, side = NO_TIME, 1.0
    if start - spread <= 2.0 * delta:  # else too far apart at the start to touch, whatever the end
        t_hit, side = _edge_edge_hit(p0, p1, q0, q1, r0, r1, s0, s1, start, _segment_distance(p1, q1, r1, s1),
                                     spread, delta, crossings_only)
    return t_hit, side


@ti.func
def edge_edge_hit_between(p0, p1, q0, q1, r0, r1, s0, s1, start, end, delta, crossings_only: ti.template()):
    """:func:`edge_edge_hit` for a caller that has the segments' distances (m) at the step's
    ``start`` and ``end`` already."""
    return _edge_edge_hit(p0, p1, q0, q1, r0, r1, s0, s1, start, end,
                          _motion_spread(p1 - p0, q1 - q0, r1 - r0, s1 - s0), delta, crossings_only)


@ti.func
def _edge_edge_hit(p0, p1, q0, q1, r0, r1, s0, s1, start, end, spread, delta, crossings_only: ti.template()):
    t_hit, side = NO_TIME, 1.0
    if start + end - spread <= 2.0 * delta:  # see _vertex_triangle_hit
        ea0, eb0, ep0 = q0 - p0, s0 - r0, r0 - p0
        k = coplanarity_cubic(ea0, (q1 - p1) - ea0, eb0, (s1 - r1) - eb0, ep0, (r1 - p1) - ep0)
        t_hit, side = _earliest_touch(k, p0, p1, q0, q1, r0, r1, s0, s1, start, delta, crossings_only, False)
    return t_hit, side


@ti.func
def _earliest_touch(k, a0, a1, b0, b1, c0, c1, d0, d1, start, delta, crossings_only: ti.template(),
                    vertex_triangle: ti.template()):
    """The earliest of cubic ``k``'s candidate times at which the four points, moving linearly,
    are closer than ``delta`` as a vertex a and a triangle (b, c, d), or as two segments (a, b)
    and (c, d); NO_TIME if none. And the side before it (see :func:`_side_before`)."""
    t_hit = NO_TIME
    side = 1.0
    times = candidate_times(k, crossings_only)
    for j in range(5):
        t = times[j]
        if t >= 0.0 and (t_hit < 0.0 or t < t_hit) and _counts(t, start, delta, crossings_only):
            a, b, c, d = a0 + t * (a1 - a0), b0 + t * (b1 - b0), c0 + t * (c1 - c0), d0 + t * (d1 - d0)
            distance = 0.0
            if ti.static(vertex_triangle):
                distance = point_triangle_distance(a, b, c, d)
            else:
                distance = _segment_distance(a, b, c, d)
            if distance < delta:
                t_hit = t
    if t_hit >= 0.0:
        side = _side_before(k, t_hit)
    return t_hit, side
