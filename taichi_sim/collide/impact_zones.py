"""Rigid impact zones: the fail-safe of the self-contact stage (on the host, in numpy).

It runs only in steps where contacts were left touching after the contact rounds, and only on
the vertices involved (usually a few dozen), so numpy on the host costs less than kernels would.
"""
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

# Pinned vertices cannot move with a zone: in the zone's rigid fit they weigh this many times
# the zone's free mass, so a zone holding a still pin stays (almost exactly) still.
PINNED_WEIGHT = 1e9
# A zone ending inside the floor or an object is moved out one surface at a time (an object's
# deepest point each time, which may leave another just inside): at most this many moves.
MAX_LIFTS = 16
# A zone whose vertices mostly (this share or more) already move by one rigid motion of an earlier
# round gives that motion to the vertices it gained, instead of being fitted again: only those
# move, so the next round looks only at their pairs. Fitted again, every vertex of a zone of
# thousands moves a little and all their pairs are collected and tested again, round after round.
ADOPT_SHARE = 0.5
# Halvings of the share of a zone's motion that ends it on the floor (see _stop_at_floor): 2^-20
# of a step's motion of a few centimetres is far below the thickness.
FLOOR_BISECTIONS = 20


class ImpactZones:
    """Groups of vertices that move as one rigid body over a step (connected components of touches).

    Args:
        mass: (n,) particle masses (kg).
        free: (n,) nonzero for particles that move; pinned ones keep their own motion, unless
            their zone cannot be resolved without moving them (see :meth:`rigidify`).
        floor: ``(point, unit normal)`` of a ground plane no zone may end below, or None.
        push_out: None, or a callable taking (m, 3) end positions (m) of a zone's moving
            vertices and returning the translation (3,) that moves the deepest of them inside
            an object onto its surface (zero when none is inside).
    """

    def __init__(self, mass: np.ndarray, free: np.ndarray, floor=None, push_out=None):
        self.mass = np.asarray(mass, float)
        self.free = np.asarray(free) != 0
        # each vertex's zone, named by one of its vertices; -1: in no zone. Arrays and a graph's
        # connected components rather than a union-find in Python: the zones of a 64 x 64 fold
        # reach thousands of vertices and are merged again every round
        self.zone = np.full(len(self.mass), -1, np.int64)
        # the rigid motion each vertex was last given this step (an index into ``motions``: the
        # zone's start centre c0, its translation and rotation, end = c0 + T + R (x0 - c0)), -1: none
        self.motion_of = np.full(len(self.mass), -1, np.int64)
        self.motions: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.refit_all = False  # merge_all was called: every zone moves at the next rigidify
        self.stuck: set[int] = set()  # vertices of touches inside one zone: their zones carry their pins
        self.floor = None if floor is None else (np.asarray(floor[0], float), np.asarray(floor[1], float))
        self.push_out = push_out

    def clear(self) -> None:
        """Forget the zones (a new step)."""
        self.zone.fill(-1)
        self.motion_of.fill(-1)
        self.motions.clear()
        self.refit_all = False
        self.stuck.clear()

    def merge(self, touches: np.ndarray) -> None:
        """Join the zones of the four vertices of each touching pair ((m, 4) vertex ids). A touch
        whose four vertices shared a zone before this call is remembered in ``stuck`` (touches of
        one call that only this call's merging puts in one zone are not: one crossing is often
        found as several touches over the same vertices)."""
        touches = np.asarray(touches, np.int64).reshape(-1, 4)
        if len(touches) == 0:
            return
        before = self.zone[touches]
        inside = (before >= 0).all(axis=1) & (before == before[:, :1]).all(axis=1)
        self.stuck.update(int(i) for i in touches[inside, 0])
        n = len(self.zone)
        in_zone = np.flatnonzero(self.zone >= 0)
        # the graph: each touch's vertices joined to its first, each zone's to the vertex naming it
        rows = np.concatenate([np.repeat(touches[:, 0], 3), in_zone])
        cols = np.concatenate([touches[:, 1:].ravel(), self.zone[in_zone]])
        graph = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n, n))
        _, component = connected_components(graph, directed=False)
        members = np.union1d(in_zone, touches.ravel())
        first = np.full(n, n, np.int64)  # each component named by its lowest vertex
        np.minimum.at(first, component[members], members)
        self.zone[members] = first[component[members]]

    def merge_all(self) -> None:
        """One zone of every vertex: the last resort, which no touch survives (the whole cloth,
        pins included, moves rigidly over the step)."""
        self.zone.fill(0)
        self.refit_all = True

    def zones(self, roots=None) -> list[np.ndarray]:
        """The vertex ids of each zone (of those named in ``roots``, when given), each sorted."""
        members = np.flatnonzero(self.zone >= 0)
        if roots is not None:
            members = members[np.isin(self.zone[members], np.fromiter(roots, np.int64))]
        order = np.argsort(self.zone[members], kind="stable")  # stable: ids stay sorted in a zone
        members = members[order]
        labels = self.zone[members]
        cuts = np.flatnonzero(np.diff(labels)) + 1
        return np.split(members, cuts) if len(members) else []

    def rigidify(self, touches: np.ndarray, x0: np.ndarray, x1: np.ndarray, v1: np.ndarray, h: float):
        """Merge ``touches`` into the zones, then move every zone they reached rigidly from its
        start ``x0`` (every zone after :meth:`merge_all`).

        A zone no touch reached keeps the rigid motion an earlier call gave it: the fit of a
        rigid displacement (rotation chord plus translation) is not that displacement again (its
        turn changes), so fitting it again would alter a motion nothing called into question and
        move vertices whose pairs the next round would then have to look at again. For the
        same reason a zone of which ADOPT_SHARE or more already moves by one motion of an earlier
        call gives that motion to the vertices it gained (:meth:`_adopt`) rather than being
        fitted again, where it holds no pins and that motion ends them outside the floor and the
        objects: the momentum of its displacements is then the earlier fit's, not its own.

        Each zone's motion keeps the linear and angular momentum of its vertices' displacements
        over the step, (x1 - x0) / h: the end positions are the exact rigid transform
        x_cm + h v_cm + R(h w) r (a share of it where the floor stops it, see below). The end
        velocities are replaced by their own rigid part at the end positions (the mass-weighted
        projection onto rigid motions: momentum kept, kinetic energy never raised).

        Pinned vertices keep their own motion, and a zone holding them is fitted with them
        weighing PINNED_WEIGHT times the zone, so that it follows a still pin exactly enough.
        Pins on scripted paths need not move rigidly together, though, and a touch inside one
        zone then survives its fit; such a zone (a touch inside it was seen: ``stuck``) and the
        last resort (:meth:`merge_all`) move their pins with them, off their paths for this
        step, as no touch may remain (the pins' owner puts them back on their paths).

        With a ``floor``, a zone whose motion would end partly below it moves only the share of
        its motion that ends its lowest vertex on it (:meth:`_stop_at_floor`): still one rigid
        motion, so still no touch inside (its moving vertices only: pins it does not carry stay,
        and a touch that leaves inside it makes it carry them in the next round). With
        ``push_out``, a zone ending partly inside an object is moved out of it, along the normal
        at its deepest point, alternating with the floor (up to MAX_LIFTS moves). Velocities are
        left to the colliders.

        Args:
            touches: (m, 4) vertex ids of touching pairs (may be empty).
            x0, x1, v1: (n, 3) start positions, end positions (m) and end velocities (m/s).
            h: the step (s).
        Returns:
            (x1, v1) as new (n, 3) arrays, changed on the moved zones' vertices only.
        """
        self.merge(touches)
        carry_all = self.refit_all
        roots = None if self.refit_all else set(self.zone[np.asarray(touches, np.int64).ravel()].tolist())
        self.refit_all = False
        carrying = set(self.zone[list(self.stuck)].tolist())
        x1, v1 = np.array(x1, float), np.array(v1, float)
        x0 = np.asarray(x0, float)
        for ids in self.zones(roots):
            carries_pins = carry_all or int(self.zone[ids[0]]) in carrying
            if not carries_pins and self._adopt(ids, x0, x1, v1):
                continue
            free = self.free[ids]
            m = self.mass[ids].copy()
            if not free.all():
                m[~free] = PINNED_WEIGHT * max(float(m[free].sum()), 1.0)
            c0 = _centre(m, x0[ids])
            r = x0[ids] - c0
            v_cm, omega = _rigid_part(m, r, (x1[ids] - x0[ids]) / h)
            moves = np.ones_like(free) if carries_pins else free
            translation, rotation = self._stop_at_floor(c0, h * v_cm, h * omega, x0[ids[moves]])
            r_end = r @ rotation.T
            # the end velocities get their own rigid part (at the end positions): the displacement
            # also holds position fixes (a plane's projection) that must not become velocity
            w_cm, spin = _rigid_part(m, r_end, v1[ids])
            shift = self._lift((c0 + translation + r_end)[moves])
            end = c0 + translation + shift + r_end
            x1[ids[moves]] = end[moves]
            v1[ids[moves]] = (w_cm + np.cross(spin, r_end))[moves]
            self.motions.append((c0, translation + shift, rotation))
            self.motion_of[ids] = -1
            self.motion_of[ids[moves]] = len(self.motions) - 1
        return x1, v1

    def _adopt(self, ids: np.ndarray, x0: np.ndarray, x1: np.ndarray, v1: np.ndarray) -> bool:
        """Give zone ``ids`` the rigid motion most of its vertices (ADOPT_SHARE or more) already
        have, moving only the others, and its velocities their own rigid part at the end
        positions (momentum kept, kinetic energy never raised); returns False, changing nothing,
        where it does not apply: no such motion, pins, or an end inside the floor or an object."""
        motion = self.motion_of[ids]
        known = motion[motion >= 0]
        if len(known) == 0 or not self.free[ids].all():
            return False
        counts = np.bincount(known)
        best = int(counts.argmax())
        if counts[best] < ADOPT_SHARE * len(ids):
            return False
        c0, translation, rotation = self.motions[best]
        gained = ids[motion != best]
        end = c0 + translation + (x0[gained] - c0) @ rotation.T
        if np.any(self._lift(end) != 0.0):
            return False
        x1[gained] = end
        self.motion_of[gained] = best
        m = self.mass[ids]
        r_end = x1[ids] - _centre(m, x1[ids])
        w_cm, spin = _rigid_part(m, r_end, v1[ids])
        v1[ids] = w_cm + np.cross(spin, r_end)
        return True

    def _stop_at_floor(self, c0: np.ndarray, translation: np.ndarray, turn: np.ndarray, x0: np.ndarray):
        """The zone's motion (``translation`` (3,) and rotation vector ``turn`` (3,) about ``c0``)
        cut short where it would end any of its moving vertices (start positions ``x0``, (m, 3))
        below the floor: the share of it, found by bisection, that ends them on it or above, as
        a rigid body that stops where it meets the ground. Returns (translation, rotation matrix).

        Why not the whole motion lifted back up (as :meth:`_lift` does for objects): a zone lying
        on the floor turns a little with the cloth falling onto it, and a turn of a few degrees
        ends one side of a zone 20 cm across a centimetre or more deep; lifted back, the whole
        zone rose that much (up to 5.4 cm), step after step, pulling its rim's springs with it.
        32 x 32 XPBD folds at 1/60 s gained energy so (peaks of 91-1832 J from 66 J in six runs,
        springs stretched up to 10-fold, more runs diverged); cut short, twelve runs peaked at
        88-176 J and a thirteenth at 454 J."""
        rotation = _rotation(turn)
        if self.floor is None or len(x0) == 0:
            return translation, rotation
        point, normal = self.floor
        r = x0 - c0

        def lowest(share: float, rotation: np.ndarray) -> float:
            return float(((c0 + share * translation + r @ rotation.T - point) @ normal).min())

        # a zone that starts below it (round-off, a vertex pressed in) may end no lower than it
        # started; what is left below is lifted by :meth:`_lift`, by no more than the start's depth
        level = min(0.0, float(((x0 - point) @ normal).min()))
        if lowest(1.0, rotation) >= level:
            return translation, rotation
        inside, outside = 0.0, 1.0
        for _ in range(FLOOR_BISECTIONS):
            share = 0.5 * (inside + outside)
            if lowest(share, _rotation(share * turn)) >= level:
                inside = share
            else:
                outside = share
        rotation = _rotation(inside * turn)
        # down onto that level exactly (by at most 2^-FLOOR_BISECTIONS of the motion)
        return inside * translation - (lowest(inside, rotation) - level) * normal, rotation

    def _lift(self, points: np.ndarray) -> np.ndarray:
        """The translation (3,) that moves ``points`` (m, 3) out of the floor and the objects."""
        shift = np.zeros(3)
        if len(points) == 0:
            return shift
        for _ in range(MAX_LIFTS):
            if self.floor is not None:
                depth = ((points + shift - self.floor[0]) @ self.floor[1]).min()
                if depth < 0.0:
                    shift -= depth * self.floor[1]
            if self.push_out is None:
                break
            out = self.push_out(points + shift)
            if not np.any(out != 0.0):
                break
            shift += out
        return shift


def _centre(m: np.ndarray, x: np.ndarray) -> np.ndarray:
    return (m[:, None] * x).sum(0) / m.sum()


def _rigid_part(m: np.ndarray, r: np.ndarray, u: np.ndarray):
    """(v_cm, w): the rigid motion v_cm + w x r nearest velocities ``u`` at offsets ``r`` from the
    centre of mass, in the kinetic-energy norm (same momentum and angular momentum)."""
    v_cm = _centre(m, u)
    momentum = (m[:, None] * np.cross(r, u - v_cm)).sum(0)
    inertia = (m[:, None, None] * ((r * r).sum(1)[:, None, None] * np.eye(3)
                                  - r[:, :, None] * r[:, None, :])).sum(0)
    return v_cm, np.linalg.pinv(inertia, rcond=1e-12) @ momentum  # a line of vertices: no spin about it


def _rotation(phi: np.ndarray) -> np.ndarray:
    """The rotation matrix by angle |phi| about phi (Rodrigues)."""
    angle = float(np.linalg.norm(phi))
    if angle == 0.0:
        return np.eye(3)
    k = phi / angle
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross
