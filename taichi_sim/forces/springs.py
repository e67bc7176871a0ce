
import numpy as np
import taichi as ti

from .. import runtime
from .base import ForceTerm

SPRING_KINDS = ("structural", "shear", "flex")


def incidence(particle_count: int, ends: np.ndarray):
    """CSR incidence of springs on particles.

    Returns (offsets (n+1,), spring_ids (2S,), others (2S,)): particle i's springs are
    ``spring_ids[offsets[i]:offsets[i+1]]``, joining it to ``others[...]``.
    """
    S = len(ends)
    owner = np.concatenate([ends[:, 0], ends[:, 1]])
    other = np.concatenate([ends[:, 1], ends[:, 0]])
    sid = np.concatenate([np.arange(S), np.arange(S)])
    order = np.argsort(owner, kind="stable")
    counts = np.bincount(owner, minlength=particle_count)
    offsets = np.zeros(particle_count + 1, dtype=np.int32)
    np.cumsum(counts, out=offsets[1:])
    return offsets, sid[order].astype(np.int32), other[order].astype(np.int32)


@ti.data_oriented
class Springs(ForceTerm):
    """Hookean springs with optional dashpots, evaluated as a per-particle gather.

    Spring s joins particles (i, j) = ends[s] with stiffness k (N/m), rest length r (m) and
    dashpot coefficient c (N s/m). With d = x_i - x_j and u = d/|d|, the force on i is
    ``-k (|d| - r) u - c ((v_i - v_j) . u) u`` and the opposite on j. A spring of zero length
    exerts no force (its direction is undefined).

    Each particle sums the springs it touches (CSR incidence), so the result is independent of
    thread scheduling (no float atomics) and bit-reproducible; every spring is evaluated twice,
    once from each end, which on a CPU costs less than atomic scatter.

    Args:
        particle_count: n.
        ends: (S, 2) int particle indices.
        rest_length, stiffness, damping: (S,) floats.
        kind: (S,) int, 0 structural, 1 shear, 2 flex (metadata for cloth; any value allowed).
    """

    name = "springs"

    def __init__(self, particle_count, ends, rest_length, stiffness, damping, kind):
        ends = np.asarray(ends, dtype=np.int32).reshape(-1, 2)
        self.spring_count = S = len(ends)
        if S == 0:
            raise ValueError("Springs needs at least one spring (a scene without springs adds no term)")
        self.ends_np = ends
        self.kind_np = np.asarray(kind, dtype=np.int8).reshape(S)
        self.damped = bool(np.any(np.asarray(damping) != 0))
        real = runtime.real()
        self.ends = ti.Vector.field(2, ti.i32, shape=S)
        self.rest = ti.field(real, shape=S)
        self.stiffness = ti.field(real, shape=S)
        self.damping = ti.field(real, shape=S)
        self.ends.from_numpy(ends)
        self.set_parameters(rest_length=rest_length, stiffness=stiffness, damping=damping)
        offsets, sid, other = incidence(particle_count, ends)
        self.offsets = ti.field(ti.i32, shape=particle_count + 1)
        self.incident = ti.field(ti.i32, shape=2 * S)
        self.other = ti.field(ti.i32, shape=2 * S)
        self.offsets.from_numpy(offsets)
        self.incident.from_numpy(sid)
        self.other.from_numpy(other)

    def set_parameters(self, *, rest_length=None, stiffness=None, damping=None) -> None:
        """Replace per-spring values (arrays of shape (S,) or scalars). Dashpots must have been
        present at construction for a nonzero ``damping`` to take effect."""
        npr = runtime.np_real()
        S = self.spring_count
        if rest_length is not None:
            self.rest.from_numpy(np.broadcast_to(np.asarray(rest_length, dtype=npr), (S,)).copy())
        if stiffness is not None:
            self.stiffness.from_numpy(np.broadcast_to(np.asarray(stiffness, dtype=npr), (S,)).copy())
        if damping is not None:
            self.damping.from_numpy(np.broadcast_to(np.asarray(damping, dtype=npr), (S,)).copy())

    def arrays(self) -> dict:
        """Spring data as numpy arrays (the npz schema's spring keys)."""
        return {
            "springs": self.ends_np.astype(np.int64),
            "rest_length": self.rest.to_numpy().astype(np.float64),
            "stiffness": self.stiffness.to_numpy().astype(np.float64),
            "spring_damping": self.damping.to_numpy().astype(np.float64),
            "spring_kind": self.kind_np.astype(np.int64),
        }

    @ti.func
    def force(self, i, y, mass_i):
        f = ti.Vector.zero(y.x.dtype, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            j = self.other[e]
            d = y.x[i] - y.x[j]
            length = d.norm()
            if length > 0.0:
                u = d / length
                f -= self.stiffness[s] * (length - self.rest[s]) * u
                if ti.static(self.damped):
                    f -= self.damping[s] * (y.v[i] - y.v[j]).dot(u) * u
        return f

    def energy(self, y) -> float:
        return float(self._energy(y))

    @ti.kernel
    def _energy(self, y: ti.template()) -> float:
        total = 0.0
        for s in range(self.spring_count):
            e = self.ends[s]
            stretch = (y.x[e[0]] - y.x[e[1]]).norm() - self.rest[s]
            total += 0.5 * self.stiffness[s] * stretch * stretch
        return total

