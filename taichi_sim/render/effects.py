"""Particle effects: how an emitter's particles look over their life (water, fire, smoke).

A :class:`Look` maps a particle's age, as a fraction u = age / lifetime in [0, 1], to a colour,
an opacity and a radius, piecewise linearly between a few keys. :class:`EffectDrawer` evaluates
it for every live particle in a Taichi kernel each frame and hands GGUI one ``scene.particles``
call with per-particle RGBA colours and radii.

What GGUI (Taichi 1.7.4) does with particles, found by drawing them offscreen
(docs/rendering-and-recording.md, Particle effects): it honours the alpha of an RGBA
``per_vertex_color`` (standard "over" blending) and ``per_vertex_radius``; it writes depth for
every particle however transparent, so a translucent particle hides whatever is drawn after it
behind it: particles are sorted far to near (``ti.algorithms.parallel_sort`` on their distance
to the eye) before they are handed over.
It lights every particle as a sphere with the scene's lights and has no additive blending and
no emissive colour, so a flame's colours are scaled up (``glow``: GGUI does not clamp colours
before lighting) for the lit sphere to keep them.
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from ..scene.visual import Emitter

#: The sort key of a dead slot: after every live particle (keys of live ones are <= 0).
DEAD = 1e30


@dataclass(frozen=True)
class Look:
    """A particle's appearance over its life, piecewise linear between keys.

    Attributes:
        ages: key ages as fractions of the lifetime, increasing from 0 to 1.
        rgba: (red, green, blue, opacity) at each key, each in [0, 1].
        radius: the drawn radius at each key, in units of the scene's particle radius.
        glow: factor on the colour handed to GGUI, so that a lit sphere shows about the key's
            colour (GGUI lights particles and has no emissive colour); 1 for lit matter.
    """

    ages: tuple[float, ...]
    rgba: tuple[tuple[float, float, float, float], ...]
    radius: tuple[float, ...]
    glow: float = 1.0

    def __post_init__(self):
        if not (len(self.ages) == len(self.rgba) == len(self.radius) >= 2):
            raise ValueError("a look needs at least two keys, each with an age, a colour and a radius")
        if self.ages[0] != 0.0 or self.ages[-1] != 1.0 or any(b <= a for a, b in zip(self.ages, self.ages[1:])):
            raise ValueError("a look's ages must increase from 0 to 1")


LOOKS: dict[str, Look] = {
    # Drops: pale blue leaving the nozzle, deeper blue with age, fading and shrinking at the end.
    "water": Look(ages=(0.0, 0.7, 1.0),
                  rgba=((0.55, 0.82, 1.00, 0.95), (0.30, 0.56, 0.92, 0.85), (0.16, 0.30, 0.55, 0.0)),
                  radius=(1.0, 1.0, 0.6)),
    # Flames: white-yellow at the burner, through orange and red to a dark, transparent ember,
    # shrinking as they cool.
    "fire": Look(ages=(0.0, 0.15, 0.45, 0.75, 1.0),
                 rgba=((1.00, 0.95, 0.65, 0.80), (1.00, 0.78, 0.22, 0.70), (1.00, 0.45, 0.06, 0.55),
                       (0.78, 0.14, 0.03, 0.30), (0.25, 0.04, 0.01, 0.0)),
                 radius=(4.0, 3.6, 2.9, 2.0, 1.0), glow=1.7),
    # Smoke: grey puffs that grow, darken a little and thin out.
    "smoke": Look(ages=(0.0, 0.3, 1.0),
                  rgba=((0.78, 0.78, 0.78, 0.45), (0.62, 0.62, 0.63, 0.30), (0.45, 0.45, 0.46, 0.0)),
                  radius=(2.0, 5.0, 10.0)),
}


def look_func(look: Look):
    """A ``@ti.func at(u) -> (rgba, radius)`` for ``look``: the colour (times ``glow``) and
    opacity as an f32 4-vector and the radius factor, at age fraction ``u`` (clamped to [0, 1]).
    The keys are compile-time constants: each look compiles its own code."""
    ages, rgba, radius, glow = look.ages, look.rgba, look.radius, look.glow
    keys = len(ages)

    @ti.func
    def at(u):
        u = ti.math.clamp(u, 0.0, 1.0)
        colour = ti.Vector(rgba[0], ti.f32)
        size = ti.cast(radius[0], ti.f32)
        for j in ti.static(range(1, keys)):
            if u > ages[j - 1]:  # the last segment u has passed fixes the value
                s = ti.min((u - ages[j - 1]) / (ages[j] - ages[j - 1]), 1.0)
                before, after = ti.Vector(rgba[j - 1], ti.f32), ti.Vector(rgba[j], ti.f32)
                colour = before + s * (after - before)
                size = radius[j - 1] + s * (radius[j] - radius[j - 1])
        colour[0] *= glow
        colour[1] *= glow
        colour[2] *= glow
        return colour, size

    return at


def evaluate_look(effect: str, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The look ``effect`` at age fractions ``u`` ((n,) array), by the same Taichi code the
    drawer runs: (n, 4) RGBA (colour times glow, opacity) and (n,) radius factors. Taichi must
    be initialised."""
    if effect not in LOOKS:
        raise ValueError(f"effect must be one of {', '.join(LOOKS)}, got {effect!r}")
    at = look_func(LOOKS[effect])

    @ti.kernel
    def run(u: ti.types.ndarray(), rgba: ti.types.ndarray(), size: ti.types.ndarray()):
        for i in range(u.shape[0]):
            c, r = at(u[i])
            for k in ti.static(range(4)):
                rgba[i, k] = c[k]
            size[i] = r

    u = np.ascontiguousarray(u, np.float32).reshape(-1)
    rgba, size = np.zeros((len(u), 4), np.float32), np.zeros(len(u), np.float32)
    run(u, rgba, size)
    return rgba, size


@ti.data_oriented
class EffectDrawer:
    """Draws an emitter's live particles with its look, sorted far to near.

    Allocated only for scenes with an emitter (a :class:`SceneDrawer` makes one then): staging
    fields of the emitter's capacity for centres, RGBA colours, radii and the sort.

    Args:
        emitter: the visual's emitter (slots, ages, lifetime, effect).
        positions: the drawer's staged (n,) f32 vec3 positions (already offset), read per frame.
        radius: the scene's particle radius (m), the unit of the look's radii.
    """

    def __init__(self, emitter: Emitter, positions, radius: float):
        if emitter.effect not in LOOKS:
            raise ValueError(f"effect must be one of {', '.join(LOOKS)}, got {emitter.effect!r}")
        self.emitter = emitter
        self.look = LOOKS[emitter.effect]
        self.at = look_func(self.look)
        self.positions = positions
        self.radius = float(radius)
        cap = emitter.capacity
        self.centers = ti.Vector.field(3, ti.f32, cap)
        self.colors = ti.Vector.field(4, ti.f32, cap)
        self.radii = ti.field(ti.f32, cap)
        self.key = ti.field(ti.f32, cap)
        self.order = ti.field(ti.i32, cap)
        self.count = 0
        self.eye = np.zeros(3)  # where the last update sorted from (m)

    def update(self, eye) -> int:
        """Gather this frame's live particles far to near from ``eye`` (m); returns how many."""
        e = self.emitter
        self.eye = np.asarray(eye, np.float64).reshape(3)
        self.count = self._keys(ti.Vector(self.eye.tolist(), ti.f32))
        if self.count:
            ti.algorithms.parallel_sort(self.key, self.order)
            # the lifetime as it is now: a particle older than the built one is not dead yet
            lifetime = e.lifetime_now() if e.lifetime_now is not None else e.lifetime
            self._fill(self.count, float(lifetime), self.radius)
        return self.count

    def draw(self, scene) -> None:
        """Declare the particles gathered by :meth:`update` on a ``ti.ui`` scene."""
        if self.count:
            scene.particles(self.centers, radius=self.radius, per_vertex_color=self.colors,
                            per_vertex_radius=self.radii, index_count=self.count)

    @ti.kernel
    def _keys(self, eye: ti.types.vector(3, ti.f32)) -> ti.i32:
        """Sort keys: minus the squared distance to the eye for live slots (the farthest first),
        :data:`DEAD` for the others; the order field starts as the identity."""
        count = 0
        for k in range(self.emitter.capacity):
            key = ti.cast(DEAD, ti.f32)
            if self.emitter.alive[k] != 0:
                key = -(self.positions[self.emitter.first + k] - eye).norm_sqr()
                count += 1
            self.key[k] = key
            self.order[k] = k
        return count

    @ti.kernel
    def _fill(self, count: ti.i32, lifetime: ti.f32, radius: ti.f32):
        for m in range(count):
            k = self.order[m]
            colour, size = self.at(ti.cast(self.emitter.age[k], ti.f32) / lifetime)
            self.centers[m] = self.positions[self.emitter.first + k]
            self.colors[m] = colour
            self.radii[m] = size * radius
