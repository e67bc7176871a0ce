"""The self-contact stage and the scene's objects (its collider parts): its pushes must not
move the cloth into them.

A mixin of :class:`~.self_contact.SelfCollision`, which owns ``obstacles`` (the scene's object
colliders, each an :class:`~taichi_sim.scene.colliders.obstacle.Obstacle`), ``time`` (the end
of the step, where the objects are) and ``thickness``. The three rules follow the floor's:

* a contact does not push a vertex within the thickness of an object towards it (the other
  side moves the whole gap);
* a free vertex the contact rounds left inside an object is put back on its surface, without
  its velocity into it (relative to the surface, which may move and spin);
* a rigid impact zone that would end partly inside an object is moved out along the normal at
  its deepest point (:meth:`_push_zone_out`, called by :class:`~.impact_zones.ImpactZones`):
  still one rigid motion, so still no touch inside it.

The object colliders ran before the stage and left the cloth outside, so these act only where
the stage's own pushes would undo that.
"""
import numpy as np
import taichi as ti

from .friction import inelastic_friction

FAR = 1e30  # the distance (m) from a point when there is no object


class KeepsOutOfObjects:
    """Mixin of :class:`~.self_contact.SelfCollision`: the objects' rules (module doc)."""

    @ti.func
    def _nearest_obstacle(self, x, reach):
        """(signed distance (m), outward unit normal, surface velocity (m/s)) of the object
        surface nearest to ``x`` at the step's end; FAR when the scene has none, or (for an
        object that searches, a mesh) none within ``reach`` (m) of its surface."""
        best = FAR * 1.0  # a variable of the default float type
        normal = ti.Vector([0.0, 1.0, 0.0])
        velocity = ti.Vector([0.0, 0.0, 0.0])
        for obstacle in ti.static(self.obstacles):
            d, n, v = obstacle.nearest_surface(x, self.time[None], reach)
            if d < best:
                best = d
                normal = n
                velocity = v
        return best, normal, velocity

    @ti.func
    def _held_by_obstacle(self, x, push):
        """A vertex at ``x`` (m) within the thickness of an object, which a correction along
        ``push`` would move towards it."""
        held = False
        if ti.static(len(self.obstacles) > 0):
            d, normal, _ = self._nearest_obstacle(x, self.thickness[None])
            held = d < self.thickness[None] and push.dot(normal) < 0.0
        return held

    @ti.kernel
    def _lift_out_of_obstacles(self, y: ti.template()) -> ti.i32:
        """Put every free vertex inside an object back on its surface, without its velocity into
        it relative to the surface; returns how many."""
        lifted = 0
        for i in y.x:
            if self.system.free[i]:
                d, normal, surface = self._nearest_obstacle(y.x[i], 0.0)
                if d < 0.0:
                    y.x[i] -= d * normal
                    y.v[i] = inelastic_friction(y.v[i], surface, normal, 0.0)
                    lifted += 1
        return lifted

    @ti.kernel
    def _obstacle_depths(self, points: ti.types.ndarray(ndim=2), depth: ti.types.ndarray(ndim=1),
                         normal: ti.types.ndarray(ndim=2)):
        for i in range(points.shape[0]):
            x = ti.Vector([points[i, 0], points[i, 1], points[i, 2]], dt=self.x_start.dtype)
            d, n, _ = self._nearest_obstacle(x, 0.0)
            depth[i] = d
            for a in ti.static(range(3)):
                normal[i, a] = n[a]

    def _push_zone_out(self, points: np.ndarray) -> np.ndarray:
        """The translation (3,) that puts the deepest of ``points`` (m, 3) inside an object on
        its surface; zero when none is inside."""
        points = np.ascontiguousarray(points, np.float64)
        depth = np.empty(len(points))
        normal = np.empty((len(points), 3))
        self._obstacle_depths(points, depth, normal)
        deepest = int(np.argmin(depth))
        if depth[deepest] >= 0.0:
            return np.zeros(3)
        return -depth[deepest] * normal[deepest]
