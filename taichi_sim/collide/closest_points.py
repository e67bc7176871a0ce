"""Closest points between a point and a triangle, and between two segments (Taichi functions)."""
import taichi as ti


@ti.func
def inside(p, a, b, c):
    """Whether p's projection onto the plane of (a, b, c) falls inside the triangle (with a
    relative tolerance of 1e-6, so a vertex crossing exactly at an edge counts)."""
    n = (b - a).cross(c - a)
    nn = n.norm_sqr()
    u = (b - p).cross(c - p).dot(n) / nn
    v = (c - p).cross(a - p).dot(n) / nn
    w = 1.0 - u - v
    return u >= -1e-6 and v >= -1e-6 and w >= -1e-6


@ti.func
def closest_barycentric(p, a, b, c):
    """Barycentric weights of the point of triangle (a, b, c) nearest p (Ericson, Real-Time
    Collision Detection, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab.dot(ap), ac.dot(ap)
    w = ti.Vector([1.0, 0.0, 0.0])
    bp = p - b
    d3, d4 = ab.dot(bp), ac.dot(bp)
    cp = p - c
    d5, d6 = ab.dot(cp), ac.dot(cp)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    if d1 <= 0.0 and d2 <= 0.0:
        w = ti.Vector([1.0, 0.0, 0.0])
    elif d3 >= 0.0 and d4 <= d3:
        w = ti.Vector([0.0, 1.0, 0.0])
    elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        w = ti.Vector([1.0 - t, t, 0.0])
    elif d6 >= 0.0 and d5 <= d6:
        w = ti.Vector([0.0, 0.0, 1.0])
    elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        w = ti.Vector([1.0 - t, 0.0, t])
    elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        w = ti.Vector([0.0, 1.0 - t, t])
    else:
        denom = 1.0 / (va + vb + vc)
        v = vb * denom
        u = vc * denom
        w = ti.Vector([1.0 - v - u, v, u])
    return w


@ti.func
def segment_parameters(p, q, r, s):
    """Parameters (a, b) in [0, 1] of the closest points p + a (q - p) and r + b (s - r) of two
    segments (Ericson, Real-Time Collision Detection, 5.1.9)."""
    d1, d2, rr = q - p, s - r, p - r
    a_, e, f = d1.dot(d1), d2.dot(d2), d2.dot(rr)
    sa, tb = 0.0, 0.0
    if a_ <= 1e-20 and e <= 1e-20:
        sa, tb = 0.0, 0.0
    elif a_ <= 1e-20:
        sa, tb = 0.0, ti.min(ti.max(f / e, 0.0), 1.0)
    else:
        c = d1.dot(rr)
        if e <= 1e-20:
            sa, tb = ti.min(ti.max(-c / a_, 0.0), 1.0), 0.0
        else:
            b_ = d1.dot(d2)
            denom = a_ * e - b_ * b_
            if denom > 1e-20 * a_ * e:
                sa = ti.min(ti.max((b_ * f - c * e) / denom, 0.0), 1.0)
            tb = (b_ * sa + f) / e
            if tb < 0.0:
                tb = 0.0
                sa = ti.min(ti.max(-c / a_, 0.0), 1.0)
            elif tb > 1.0:
                tb = 1.0
                sa = ti.min(ti.max((b_ - c) / a_, 0.0), 1.0)
    return ti.Vector([sa, tb])
