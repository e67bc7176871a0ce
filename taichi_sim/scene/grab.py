"""Mouse grab as an API: pick the particle nearest a ray, pull it toward a moving point, release."""
import numpy as np


class Grabber:
    """Grab a particle of a scene that was built with grab enabled.

    The pull is a stiff spring toward the target (a force term inside f: see
    :class:`taichi_sim.forces.GrabSpring`); moving the target between steps drags the particle.
    """

    def __init__(self, scene, spring):
        self.scene = scene
        self.spring = spring
        self.particle: int | None = None
        self.moves = 0  # bumped by grab, drag_to and release: the system changed from outside

    def pick(self, origin, direction, max_distance: float = np.inf) -> int | None:
        """The free particle closest to the ray origin + s direction (s > 0), within
        ``max_distance`` (m) of it, preferring the nearest along the ray among near-ties; None if
        there is none. Does not grab it."""
        origin = np.asarray(origin, float)
        direction = np.asarray(direction, float)
        direction = direction / np.linalg.norm(direction)
        x = self.scene.state.to_numpy()[0].astype(float)
        free = self.scene.system.free.to_numpy().astype(bool)
        rel = x - origin
        along = rel @ direction
        distance = np.linalg.norm(rel - along[:, None] * direction, axis=1)
        candidates = free & (along > 0) & (distance <= max_distance)
        if not candidates.any():
            return None
        # Near-ties (within 10% of the best distance) go to the particle nearest the eye.
        best = distance[candidates].min()
        close = candidates & (distance <= best * 1.1 + 1e-12)
        return int(np.flatnonzero(close)[np.argmin(along[close])])

    def grab(self, particle: int, target=None) -> None:
        """Start pulling ``particle`` toward ``target`` (default: where it is now)."""
        if target is None:
            target = self.scene.state.to_numpy()[0][particle]
        self.particle = int(particle)
        self.spring.hold(self.particle, target)
        self.moves += 1

    def drag_to(self, target) -> None:
        """Move the target point (m) of the held particle."""
        if self.particle is not None:
            self.spring.hold(self.particle, target)
            self.moves += 1

    def release(self) -> None:
        self.particle = None
        self.spring.release()
        self.moves += 1
