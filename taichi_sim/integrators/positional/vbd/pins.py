"""Scripted pins moved inside vbd's solve, under the same bounds as every other vertex.

A scene's kinematic pins (:class:`~taichi_sim.scene.kinematic.KinematicPins`, the twist's
turning sides) are normally put where their script says after each step, a jump no integrator
sees. With self-contact in vbd's solve such a jump breaks the solve's guarantee: the bounds
keep each vertex within ``bound_fraction`` of its distance to its nearest contact partner
between two detections, and a pin that jumps further can carry its triangles through the cloth
piled round it (the 32 x 32 `cloth-twist` at 1/60 s intersected in 76 of 121 frames).

So vbd takes the pins over (the scene leaves their post-step event out, ``takeover``): in
each piece of a substep the pins move from where they are to where the script puts them at the
piece's end, in the solve, where the other vertices see them, and a piece is made short enough
that no pin moves further than its bound (the script's path is not linear in time, so the
length is found by shortening until it fits). A pin pressed against the cloth has a small bound
and makes short pieces: each piece is a detection and its sweeps (:mod:`.pieces`, docs/vbd-contact.md, "Scripted pins").
"""
import numpy as np
import taichi as ti

from .... import runtime

FIT = 0.9  # a shortened piece aims at this share of the pins' bound (the path bends)


@ti.data_oriented
class DrivenPins:
    """The pins of one scene moved by vbd (module docstring).

    Args:
        part: the scene's kinematic part (``ids_np``: (k,) particle ids; ``path.at(t)`` ->
            ((k, 3) positions (m), (k, 3) velocities (m/s))).
        contact: the solve's :class:`~.contact.SolveContact` with self-contact (its
            ``nearest`` distances and ``fraction`` make each pin's bound).
        n: particles of the system.
    """

    def __init__(self, part, contact, n: int):
        real = runtime.real()
        self.part, self.contact = part, contact
        self.count = len(part.ids_np)
        self.ids = ti.field(ti.i32, shape=max(1, self.count))
        self.ids.from_numpy(part.ids_np.astype(np.int32) if self.count else np.zeros(1, np.int32))
        self.driven = ti.field(ti.i32, shape=n)  # 1: a pin this moves
        self.target = ti.Vector.field(3, real, shape=n)  # where a pin is at the piece's end (m)
        self.velocity = ti.Vector.field(3, real, shape=n)  # the script's velocity there (m/s)
        self._mark()

    @ti.kernel
    def _mark(self):
        for k in range(self.count):
            self.driven[self.ids[k]] = 1

    def plan(self, x, t: float, length: float) -> float:
        """The length (s) of the next piece from time ``t`` (s), at most ``length``: the longest
        whose pin moves from positions ``x`` (the (n,) vec3 field, where the last detection
        found them) all stay within their bounds. Loads the targets for it. 0.0 when the
        piece would have to be shorter than ``length`` / 2**20 (a pin the cloth cannot let by)."""
        npr = runtime.np_real()
        piece = length
        while piece >= length * 2.0 ** -20:
            where, speed = self.part.path.at(t + piece)
            worst = self._load(x, where.astype(npr), speed.astype(npr))
            if worst <= 1.0:
                return piece
            piece *= min(0.5, FIT / worst)
        return 0.0

    @ti.kernel
    def _load(self, x: ti.template(), where: ti.types.ndarray(), speed: ti.types.ndarray()) -> ti.f32:
        """Put the targets in place; return the largest ratio of a pin's move to its bound."""
        worst = ti.cast(0.0, x.dtype)
        for k in range(self.count):
            i = self.ids[k]
            p = ti.Vector([where[k, 0], where[k, 1], where[k, 2]], dt=x.dtype)
            self.target[i] = p
            self.velocity[i] = ti.Vector([speed[k, 0], speed[k, 1], speed[k, 2]], dt=x.dtype)
            # the shift is zero on a scene with pins: bounds are measured from the detection
            bound = self.contact.fraction * self.contact.nearest[i]
            move = (p - x[i]).norm()
            ratio = ti.cast(0.0, x.dtype)
            if move > 0.0:
                ratio = move / ti.max(bound, 1e-30)
            ti.atomic_max(worst, ratio)
        return ti.cast(worst, ti.f32)
