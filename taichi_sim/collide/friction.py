"""The velocity response every object collider shares (the scene's colliders and the self-contact
stage's objects): inelastic normal, Coulomb friction."""
import taichi as ti


@ti.func
def inelastic_friction(v, v_surface, n, mu):
    """The particle's velocity after touching a surface moving at ``v_surface`` with outward
    normal ``n`` (unit) and friction ``mu``: an approaching normal relative velocity is removed,
    and the tangential relative velocity shrinks by mu * |that normal velocity| (Coulomb's
    impulse bound), never reversing. A separating particle keeps its velocity."""
    rel = v - v_surface
    vn = rel.dot(n)
    out = v
    if vn < 0.0:
        tangential = rel - vn * n
        speed_t = tangential.norm()
        scale = 1.0
        if speed_t > 0.0:
            scale = ti.max(0.0, 1.0 + mu * vn / speed_t)
        out = v_surface + scale * tangential
    return out
