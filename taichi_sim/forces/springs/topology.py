"""The CSR incidence of springs (or triangles) on particles, built with numpy."""
import numpy as np


def incidence_of(particle_count: int, elements: np.ndarray):
    """CSR incidence of elements (springs (S, 2), triangles (T, 3)) on particles.

    Returns (offsets (n+1,), element_ids, slots): particle i belongs to the elements
    ``element_ids[offsets[i]:offsets[i+1]]``, as vertex ``slots[...]`` of each. A negative id
    is an empty slot (an element with fewer vertices than its row) and belongs to no particle.
    """
    count, arity = elements.shape
    owner = elements.T.ravel()
    element = np.tile(np.arange(count), arity)
    slot = np.repeat(np.arange(arity), count)
    if (owner < 0).any():
        keep = owner >= 0
        owner, element, slot = owner[keep], element[keep], slot[keep]
    order = np.argsort(owner, kind="stable")
    offsets = np.zeros(particle_count + 1, dtype=np.int32)
    np.cumsum(np.bincount(owner, minlength=particle_count), out=offsets[1:])
    return offsets, element[order].astype(np.int32), slot[order].astype(np.int32)


def incidence(particle_count: int, ends: np.ndarray):
    """CSR incidence of springs on particles.

    Returns (offsets (n+1,), spring_ids (2S,), others (2S,)): particle i's springs are
    ``spring_ids[offsets[i]:offsets[i+1]]``, joining it to ``others[...]``.
    """
    offsets, sid, slot = incidence_of(particle_count, ends)
    return offsets, sid, ends[sid, 1 - slot].astype(np.int32)
