"""Membrane materials: the parameters in physical units (checked), and per material the energy
density, its first Piola-Kirchhoff stress and its Hessian in F, for the constant-strain
triangles of :class:`~taichi_sim.forces.membrane.term.Membrane`.

Notation: F = [f0 f1] (3x2, the columns are 3-vectors) maps the triangle's rest frame to the
world; C = F^T F; E = (C - I) / 2. Densities are per unit rest area (J/m^2), stresses P = dpsi/dF
are 3x2 (N/m) and a Hessian is the 6x6 d^2 psi / dF^2 in the column order (f0, f1) (N/m).
"""

import math
from dataclasses import dataclass

import taichi as ti

from ...errors import ConfigError

MODELS = ("stvk", "neohookean")


def _finite(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"parameter {name}: must be a finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class MembraneMaterial:
    """A plane-stress membrane: ``model`` ('stvk' or 'neohookean'), the stretch modulus E t
    (N/m), Poisson's ratio nu in (-1, 0.5) and a viscous ``damping`` time (s: the strain rate's
    stress is ``damping`` times the elastic stress the same strain would give at rest)."""

    model: str
    stretch_modulus: float
    poisson_ratio: float
    damping: float = 0.0

    @classmethod
    def from_parameters(cls, model: str, *, stretch_modulus=None, youngs_modulus=None, thickness=None,
                        poisson_ratio=0.3, damping=0.0) -> "MembraneMaterial":
        """The material from a ``stretch_modulus`` (N/m) or from ``youngs_modulus`` (Pa) times
        ``thickness`` (m). ConfigError naming the parameter for a non-finite value, a modulus or
        thickness <= 0, nu outside (-1, 0.5) or a negative damping."""
        if model not in MODELS:
            raise ConfigError(f"parameter material: membrane model must be one of {', '.join(MODELS)}, got {model!r}")
        if stretch_modulus is None:
            if youngs_modulus is None or thickness is None:
                raise ConfigError("membrane: give stretch_modulus (N/m), or youngs_modulus (Pa) and thickness (m)")
            young = _finite("youngs_modulus", youngs_modulus)
            if not young > 0:
                raise ConfigError(f"parameter youngs_modulus: must be > 0 Pa, got {young}")
            thick = _finite("thickness", thickness)
            if not thick > 0:
                raise ConfigError(f"parameter thickness: must be > 0 m, got {thick}")
            stretch_modulus = young * thick
        stretch = _finite("stretch_modulus", stretch_modulus)
        if not stretch > 0:
            raise ConfigError(f"parameter stretch_modulus: must be > 0 N/m, got {stretch}")
        nu = _finite("poisson_ratio", poisson_ratio)
        if not -1.0 < nu < 0.5:
            raise ConfigError(f"parameter poisson_ratio: must be in (-1, 0.5), got {nu}")
        damp = _finite("membrane_damping", damping)
        if not damp >= 0:
            raise ConfigError(f"parameter membrane_damping: must be >= 0 s, got {damp}")
        return cls(model, stretch, nu, damp)

    @property
    def mu(self) -> float:
        """Shear modulus of the plane-stress membrane, E t / (2 (1 + nu)) (N/m)."""
        return self.stretch_modulus / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def lam(self) -> float:
        """First Lame parameter of the plane-stress membrane, E t nu / (1 - nu^2) (N/m)."""
        nu = self.poisson_ratio
        return self.stretch_modulus * nu / (1.0 - nu * nu)


@ti.func
def _cross_matrix(a):
    """[a]x (3x3): [a]x b = a x b."""
    return ti.Matrix([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


@ti.func
def sym_outer(a, scale):
    """scale a a^T (3x3, symmetric) as its six entries (xx, yy, zz, xy, xz, yz): a corner's
    block is a sum of such terms, which cost fewer products in six entries than in nine."""
    b = scale * a
    return ti.Vector([b[0] * a[0], b[1] * a[1], b[2] * a[2], b[0] * a[1], b[0] * a[2], b[1] * a[2]])


@ti.func
def sym_entries(h):
    """The six entries (xx, yy, zz, xy, xz, yz) of the symmetric 3x3 ``h``."""
    return ti.Vector([h[0, 0], h[1, 1], h[2, 2], h[0, 1], h[0, 2], h[1, 2]])


@ti.func
def sym_matrix(e):
    """The symmetric 3x3 of six entries (xx, yy, zz, xy, xz, yz)."""
    return ti.Matrix([[e[0], e[3], e[4]], [e[3], e[1], e[5]], [e[4], e[5], e[2]]])


@ti.func
def set_block(h: ti.template(), c: ti.template(), d: ti.template(), block):
    for r, s in ti.static(ti.ndrange(3, 3)):
        h[3 * c + r, 3 * d + s] = block[r, s]


@ti.func
def _unit(c: ti.template()):
    """The 2-vector e_c (c = 0, 1 at compile time): F's column c."""
    return ti.Vector([1.0 - c, 1.0 * c])


@ti.func
def _assemble(pair: ti.template(), f0, f1, mu, lam):
    """The 6x6 in F's columns whose 3x3 block (c, d) is ``pair``(f0, f1, mu, lam, e_c, e_d)."""
    h = ti.Matrix.zero(float, 6, 6)
    for c, d in ti.static(ti.ndrange(2, 2)):
        set_block(h, c, d, pair(f0, f1, mu, lam, _unit(c), _unit(d)))
    return h


@ti.func
def _shear_pair(f0, f1, mu, lam, r, s):
    """sum_cd r_c s_d of the PSD part mu (delta_cd (f0 f0^T + f1 f1^T) + f_d f_c^T)
    + lam f_c f_d^T of StVK's Hessian (also the viscous stress's velocity Jacobian), for two
    weight 2-vectors r, s: mu ((r.s) F F^T + (F s)(F r)^T) + lam (F r)(F s)^T (3x3). As a
    6x6 (:func:`_assemble`) it is PSD when mu >= 0 and mu + lam >= 0, which holds for every
    nu in (-1, 0.5)."""
    fr = r[0] * f0 + r[1] * f1
    fs = s[0] * f0 + s[1] * f1
    both = f0.outer_product(f0) + f1.outer_product(f1)
    return mu * (r.dot(s) * both + fs.outer_product(fr)) + lam * fr.outer_product(fs)


@ti.func
def _green(f0, f1):
    """E = (F^T F - I) / 2 as (e00, e11, e01)."""
    return 0.5 * (f0.dot(f0) - 1.0), 0.5 * (f1.dot(f1) - 1.0), 0.5 * f0.dot(f1)


@ti.func
def stvk(f0, f1, mu, lam):
    """Saint Venant-Kirchhoff: psi = mu |E|^2 + lam/2 (tr E)^2 and P = F S with
    S = 2 mu E + lam tr(E) I. Returns (psi (J/m^2), p0, p1 (the columns of P, N/m))."""
    e00, e11, e01 = _green(f0, f1)
    trace = e00 + e11
    psi = mu * (e00 * e00 + 2.0 * e01 * e01 + e11 * e11) + 0.5 * lam * trace * trace
    s00 = 2.0 * mu * e00 + lam * trace
    s11 = 2.0 * mu * e11 + lam * trace
    s01 = 2.0 * mu * e01
    return psi, s00 * f0 + s01 * f1, s01 * f0 + s11 * f1


@ti.func
def stvk_pair(f0, f1, mu, lam, r, s):
    """sum_cd r_c s_d d^2psi/dF_c dF_d of :func:`stvk` (3x3) for weight 2-vectors r, s:
    (r^T S s) I + mu ((r.s) F F^T + (F s)(F r)^T) + lam (F r)(F s)^T. With r, s two corners'
    shape gradients it is their block of the triangle's Hessian per unit area."""
    e00, e11, e01 = _green(f0, f1)
    trace = e00 + e11
    s00 = 2.0 * mu * e00 + lam * trace
    s11 = 2.0 * mu * e11 + lam * trace
    s01 = 2.0 * mu * e01
    rss = s00 * r[0] * s[0] + s01 * (r[0] * s[1] + r[1] * s[0]) + s11 * r[1] * s[1]
    return rss * ti.Matrix.identity(float, 3) + _shear_pair(f0, f1, mu, lam, r, s)


@ti.func
def stvk_hessian(f0, f1, mu, lam):
    """d^2 psi / dF^2 of :func:`stvk` (6x6): S_cd I + mu (delta_cd (f0 f0^T + f1 f1^T)
    + f_d f_c^T) + lam f_c f_d^T (:func:`stvk_pair` block by block)."""
    return _assemble(stvk_pair, f0, f1, mu, lam)


@ti.func
def stvk_corner(f0, f1, mu, lam, u, scale):
    """A corner's share of :func:`stvk` for its shape gradient u (2-vector, 1/m), times
    ``scale`` (the rest area, m^2): (scale P u (3, N: the corner's force, negated), scale
    :func:`stvk_pair` (u, u) projected to PSD (:func:`project_psd3`): its own block of the
    triangle's Hessian (N/m), as :func:`sym_entries`)."""
    e00, e11, e01 = _green(f0, f1)
    trace = e00 + e11
    s00 = 2.0 * mu * e00 + lam * trace
    s11 = 2.0 * mu * e11 + lam * trace
    s01 = 2.0 * mu * e01
    stress = (scale * (s00 * u[0] + s01 * u[1])) * f0 + (scale * (s01 * u[0] + s11 * u[1])) * f1
    return stress, scale * sym_entries(project_psd3(stvk_pair(f0, f1, mu, lam, u, u)))


@ti.func
def _area_ratio(f0, f1):
    """(J = |f0 x f1|, the unit normal n, 1/J), with n = 0 and 1/J = 0 for a collapsed triangle
    (no normal, no curvature of J). Branch-free, so that the stress and a Hessian of one
    triangle in one kernel share it (the compiler merges identical pure expressions)."""
    w = f0.cross(f1)
    jac = w.norm()
    inv = ti.select(jac > 1e-12 * (f0.dot(f0) + f1.dot(f1)), 1.0 / jac, 0.0 * jac)
    return jac, w * inv, inv


@ti.func
def neohookean(f0, f1, mu, lam):
    """A stable Neo-Hookean membrane (after Smith et al. 2018): psi = mu/2 (I_C - 2)
    - mu (J - 1) + l/2 (J - 1)^2 with I_C = |f0|^2 + |f1|^2, J = |f0 x f1| (the area ratio)
    and l = lam + mu, Smith et al.'s reparametrisation in 2D: linearised, this psi is
    mu |eps|^2 + (l - mu)/2 (tr eps)^2, so the Lame parameters ``mu``, ``lam`` given mean what
    they mean for StVK and the two models agree at small strain. Zero at rest with zero
    stress, no log: the energy stays finite as a triangle collapses (J -> 0), where log-based
    forms blow up. P's columns are mu f_c + (l (J - 1) - mu) q_c with q = dJ/dF
    (q0 = f1 x n, q1 = n x f0, n the unit normal); the Hessian is
    mu I + l q q^T + (l (J - 1) - mu) d^2J/dF^2 with d^2J/dF^2 = G^T (I - n n^T) G / J + N,
    G = [-[f1]x, [f0]x], N = [[0, -[n]x], [[n]x, 0]].
    Returns (psi (J/m^2), p0, p1 (the columns of P, N/m))."""
    lam = lam + mu
    jac, n, inv = _area_ratio(f0, f1)
    psi = 0.5 * mu * (f0.dot(f0) + f1.dot(f1) - 2.0) - mu * (jac - 1.0) + 0.5 * lam * (jac - 1.0) ** 2
    coef = lam * (jac - 1.0) - mu
    return psi, mu * f0 + coef * f1.cross(n), mu * f1 + coef * n.cross(f0)


@ti.func
def neohookean_pair(f0, f1, mu, lam, r, s):
    """sum_cd r_c s_d d^2psi/dF_c dF_d of :func:`neohookean` (3x3) for weight 2-vectors r, s:
    with G_r = sum_c r_c G_c = [a]x, a = r1 f0 - r0 f1 (b likewise for s) and q_r = sum_c r_c q_c,
    mu (r.s) I + l q_r q_s^T + (coef / J) ((a.b) I - b a^T - (n x a)(n x b)^T)
    + coef (r1 s0 - r0 s1) [n]x (see :func:`neohookean`)."""
    lam = lam + mu
    jac, n, inv = _area_ratio(f0, f1)
    coef = lam * (jac - 1.0) - mu
    qr = r[0] * f1.cross(n) + r[1] * n.cross(f0)
    qs = s[0] * f1.cross(n) + s[1] * n.cross(f0)
    a = r[1] * f0 - r[0] * f1
    b = s[1] * f0 - s[0] * f1
    curved = a.dot(b) * ti.Matrix.identity(float, 3) - b.outer_product(a) - n.cross(a).outer_product(n.cross(b))
    return (mu * r.dot(s)) * ti.Matrix.identity(float, 3) + lam * qr.outer_product(qs) + (coef * inv) * curved \
        + (coef * (r[1] * s[0] - r[0] * s[1])) * _cross_matrix(n)


@ti.func
def neohookean_hessian(f0, f1, mu, lam):
    """d^2 psi / dF^2 of :func:`neohookean` (6x6; see there): :func:`neohookean_pair` block by
    block."""
    return _assemble(neohookean_pair, f0, f1, mu, lam)


@ti.func
def neohookean_corner(f0, f1, mu, lam, u, scale):
    """A corner's share of :func:`neohookean` for its shape gradient u (2-vector, 1/m), times
    ``scale`` (the rest area, m^2), the stress and the block from one normal: (scale P u (3,
    N: the corner's force, negated), scale :func:`neohookean_pair` (u, u) projected to PSD,
    in closed form: its own block of the triangle's Hessian (N/m), as :func:`sym_entries`).

    With a = u1 f0 - u0 f1 (in the triangle's plane) the stress's q_u = u0 q0 + u1 q1 is
    n x a, so P u = mu F u + coef (n x a). With r = s = u the [n]x term of the pair cancels
    and the curvature term (coef / J) (|a|^2 I - a a^T - (n x a)(n x a)^T) is
    (coef / J) |a|^2 n n^T; the rest, mu |u|^2 I + l q_u q_u^T, is PSD with q_u in the plane:
    n is an eigenvector, of eigenvalue mu |u|^2 + coef |a|^2 / J, which the projection raises
    to 0 where it is negative (a triangle not stretched by mu / l in area), exactly as
    :func:`project_psd3` would (tests/test_vbd_membrane.py checks it against the nearest PSD
    matrix to the block)."""
    lam = lam + mu
    jac, n, inv = _area_ratio(f0, f1)
    coef = lam * (jac - 1.0) - mu
    a = u[1] * f0 - u[0] * f1
    q = n.cross(a)
    shear = mu * u.dot(u)
    normal = ti.max(shear + coef * inv * a.dot(a), 0.0) - shear
    along = scale * mu
    stress = (along * u[0]) * f0 + (along * u[1]) * f1 + (scale * coef) * q
    block = sym_outer(q, scale * lam) + sym_outer(n, scale * normal)
    iso = scale * shear
    return stress, block + ti.Vector([iso, iso, iso, 0.0, 0.0, 0.0])


@ti.func
def viscous(f0, f1, d0, d1, mu, lam, beta):
    """The viscous stress of strain rate Edot = sym(F^T Fdot) (Fdot = [d0 d1], 1/s): the
    dissipation density R = beta (mu |Edot|^2 + lam/2 (tr Edot)^2) (W/m^2) and the columns of
    P_v = dR/dFdot = beta F (2 mu Edot + lam tr(Edot) I) (N/m)."""
    e00 = f0.dot(d0)
    e11 = f1.dot(d1)
    e01 = 0.5 * (f0.dot(d1) + f1.dot(d0))
    trace = e00 + e11
    r = beta * (mu * (e00 * e00 + 2.0 * e01 * e01 + e11 * e11) + 0.5 * lam * trace * trace)
    s00 = beta * (2.0 * mu * e00 + lam * trace)
    s11 = beta * (2.0 * mu * e11 + lam * trace)
    s01 = beta * 2.0 * mu * e01
    return r, s00 * f0 + s01 * f1, s01 * f0 + s11 * f1


@ti.func
def viscous_jacobian(f0, f1, mu, lam, beta):
    """dP_v/dFdot (6x6, N s/m): beta times StVK's PSD part (:func:`_shear_pair`)."""
    return beta * _assemble(_shear_pair, f0, f1, mu, lam)


@ti.func
def viscous_corner(f0, f1, d0, d1, mu, lam, beta, u, scale, block_scale):
    """A corner's share of :func:`viscous` for its shape gradient u (2-vector, 1/m), at
    Fdot = [d0 d1] (1/s): (``scale`` P_v u (3; scale the rest area (m^2): N, the corner's
    viscous force, negated), ``block_scale`` sum_cd u_c u_d dP_v/dFdot_cd (block_scale the
    area over dt: N/m), PSD: beta (mu |u|^2 F F^T + (mu + lam) (F u)(F u)^T) (:func:`_shear_pair`
    at r = s = u), as :func:`sym_entries`, summed as beta (mu a a^T + (2 mu + lam) (F u)(F u)^T))."""
    e00 = f0.dot(d0)
    e11 = f1.dot(d1)
    e01 = 0.5 * (f0.dot(d1) + f1.dot(d0))
    trace = e00 + e11
    s00 = beta * (2.0 * mu * e00 + lam * trace)
    s11 = beta * (2.0 * mu * e11 + lam * trace)
    s01 = beta * 2.0 * mu * e01
    stress = (scale * (s00 * u[0] + s01 * u[1])) * f0 + (scale * (s01 * u[0] + s11 * u[1])) * f1
    # |u|^2 F F^T = (F u)(F u)^T + a a^T, a = u1 f0 - u0 f1 (the rows of F in u's frame):
    # two rank-one terms, and a is the Neo-Hookean corner's own
    a = u[1] * f0 - u[0] * f1
    block = sym_outer(a, block_scale * beta * mu) + sym_outer(u[0] * f0 + u[1] * f1, block_scale * beta * (2.0 * mu + lam))
    return stress, block


@ti.func
def project_psd(h):
    """The nearest positive semi-definite matrix to the symmetric 6x6 ``h`` (Frobenius norm):
    negative eigenvalues set to zero. A Cholesky attempt first: most elements near rest or
    stretched are already PSD and skip the eigen-decomposition (cyclic Jacobi rotations,
    stopped when the off-diagonal part is below 1e-14 of the matrix, at most 12 sweeps)."""
    # LDL^T of h + 1e-9 tr(h)/6 I with pivots > 0 (about 70 flops) shows h has no eigenvalue
    # below -1e-9 of its mean: kept as it is. At rest the elements are PSD but singular (a
    # vertex moved along the normal strains nothing), so the unshifted test would fail there.
    shift = 0.0 * h[0, 0]
    for k in ti.static(range(6)):
        shift += h[k, k]
    shift = 1e-9 * ti.max(shift, 0.0) / 6.0 + 1e-300
    ok = True
    work = h
    for k in ti.static(range(6)):
        work[k, k] += shift
    for k in range(6):
        if ok:
            if work[k, k] <= 0.0:
                ok = False
            else:
                for r in range(k + 1, 6):
                    factor = work[r, k] / work[k, k]
                    for c in range(k + 1, r + 1):
                        work[r, c] -= factor * work[c, k]
    out = h
    if not ok:
        a = h
        v = ti.Matrix.identity(float, 6)
        scale = 0.0 * h[0, 0]
        for r in range(6):
            for c in range(6):
                scale += h[r, c] * h[r, c]
        for sweep in range(12):
            off = 0.0 * scale
            for p in range(5):
                for q in range(p + 1, 6):
                    off += a[p, q] * a[p, q]
            if off <= 1e-28 * scale:
                break
            for p in range(5):
                for q in range(p + 1, 6):
                    apq = a[p, q]
                    if apq != 0.0:
                        theta = 0.5 * (a[q, q] - a[p, p]) / apq
                        t = ti.select(theta >= 0.0, 1.0, -1.0) / (ti.abs(theta) + ti.sqrt(theta * theta + 1.0))
                        cos = 1.0 / ti.sqrt(t * t + 1.0)
                        sin = t * cos
                        for k in range(6):
                            akp, akq = a[k, p], a[k, q]
                            a[k, p] = cos * akp - sin * akq
                            a[k, q] = sin * akp + cos * akq
                        for k in range(6):
                            apk, aqk = a[p, k], a[q, k]
                            a[p, k] = cos * apk - sin * aqk
                            a[q, k] = sin * apk + cos * aqk
                        for k in range(6):
                            vkp, vkq = v[k, p], v[k, q]
                            v[k, p] = cos * vkp - sin * vkq
                            v[k, q] = sin * vkp + cos * vkq
        out = ti.Matrix.zero(float, 6, 6)
        for k in range(6):
            lam_k = ti.max(a[k, k], 0.0)
            for r in range(6):
                for c in range(6):
                    out[r, c] += lam_k * v[r, k] * v[c, k]
    return out


@ti.func
def project_psd3(h):
    """The nearest positive semi-definite matrix to the symmetric 3x3 ``h`` (Frobenius norm):
    negative eigenvalues set to zero. Sylvester's test first (the leading minors of h plus
    1e-9 of its mean eigenvalue are > 0: about 20 flops), so a block that is already PSD, as
    near rest or stretched, skips the eigen-decomposition."""
    shift = 1e-9 * ti.max(h[0, 0] + h[1, 1] + h[2, 2], 0.0) / 3.0
    work = h + shift * ti.Matrix.identity(float, 3)
    minor = work[0, 0] * work[1, 1] - work[0, 1] * work[1, 0]
    out = h
    if not (work[0, 0] > 0.0 and minor > 0.0 and work.determinant() > 0.0):
        values, vectors = ti.sym_eig(h)
        out = ti.Matrix.zero(float, 3, 3)
        for k in ti.static(range(3)):
            v = ti.Vector([vectors[0, k], vectors[1, k], vectors[2, k]])
            out += ti.max(values[k], 0.0) * v.outer_product(v)
    return out
