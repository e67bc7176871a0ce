"""What the cloth's self-contact stage asks of an object collider: where its surface is."""

import numpy as np
import taichi as ti

from ...collide.objects import FAR


@ti.data_oriented
class Obstacle:
    """Mixin of the object colliders (each scene part with ``is_obstacle``), read by
    :class:`~taichi_sim.collide.SelfCollision`, which must not push the cloth into an object.

    A collider using it has ``count`` objects on ``path`` (:class:`~.path.PathFields`) and the
    ``ti.func``s ``distance(k, q)`` (signed, m, negative inside) and ``normal(k, q)`` (outward
    unit) at q, a point in object k's frame, and ``surface_velocity(k, t, r)`` (m/s); in Python,
    its ``paths`` (:class:`~.path.SpherePath`), the time ``t`` it was last moved to, and the
    ``key`` of its npz keys (``sphere``, ``capsule``, ``box``)."""

    is_obstacle = True  # (the ScenePart flag the builder reads to hand it to self-contact)
    # ``count``, ``path``, ``friction`` and the per-object ``distance``/``normal``/``surface_velocity``
    # above, which the VBD solve's contacts read object by object (a mesh has none of them)
    shape_functions = True

    def centers(self) -> np.ndarray:
        """(K, 3) float64: the centres (m) now."""
        return self.centers_at(self.t)[f"{self.key}_center"]

    def centers_at(self, t: float) -> dict[str, np.ndarray]:
        """``{"sphere_center": (K, 3)}`` (or ``capsule_center``, ``box_center``): the centres (m)
        at time t (s) on the paths as they are now (a run keeps them with its saved frames)."""
        return {f"{self.key}_center": np.asarray([p.at(t)[0] for p in self.paths], np.float64).reshape(-1, 3)}

    @ti.func
    def nearest_surface(self, x, t, reach):
        """(signed distance (m, negative inside), outward unit normal, surface velocity (m/s))
        of the nearest of this collider's objects to the point ``x`` (m) at time ``t`` (s);
        (FAR, +y, 0) when it has none. ``reach`` (m): how far outside a surface the caller
        cares (a collider that searches may answer FAR beyond it; these shapes are exact)."""
        best = FAR * 1.0  # a variable of the default float type
        normal = ti.Vector([0.0, 1.0, 0.0])
        velocity = ti.Vector([0.0, 0.0, 0.0])
        for k in range(self.count):
            q = x - self.path.center(k, t)
            d = self.distance(k, q)
            if d < best:
                best = d
                normal = self.normal(k, q)
                velocity = self.surface_velocity(k, t, q)
        return best, normal, velocity
