"""Colourings of a spring graph for Gauss-Seidel sweeps in parallel: of its edges (springs of one
colour share no particle: XPBD) and of its vertices (particles of one colour share no spring,
triangle or bending stencil: VBD, the elements given as their pairs by :func:`element_pairs`)."""
from __future__ import annotations

import numpy as np


def colour_springs(particle_count: int, ends: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """Greedy edge colouring of the springs ``ends`` ((S, 2) particle indices).

    Returns ``(order, starts)``: ``order`` ((S,) int32) lists the springs colour by colour, and
    colour c holds ``order[starts[c]:starts[c + 1]]``. Greedy colouring in input order uses at
    most 2 D - 1 colours (D the largest number of springs at a particle); on the 12-neighbour
    cloth grid it uses 12 to 16. Springs with both ends on the same particle are rejected.
    """
    ends = np.asarray(ends, dtype=np.int64).reshape(-1, 2)
    if len(ends) and np.any(ends[:, 0] == ends[:, 1]):
        raise ValueError("ends: a spring joins a particle to itself")
    # used[i] is a bit mask of the colours already taken at particle i (Python ints: unbounded).
    used = [0] * particle_count
    colours = np.empty(len(ends), dtype=np.int64)
    for s, (i, j) in enumerate(ends.tolist()):
        taken = used[i] | used[j]
        c = (~taken & (taken + 1)).bit_length() - 1  # lowest clear bit
        colours[s] = c
        used[i] |= 1 << c
        used[j] |= 1 << c
    order = np.argsort(colours, kind="stable").astype(np.int32)
    count = int(colours.max()) + 1 if len(ends) else 0
    starts = np.searchsorted(colours[order], np.arange(count + 1)).tolist()
    return order, starts


def colour_vertices(particle_count: int, ends: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """Greedy vertex colouring of the graph whose edges are the springs ``ends`` ((S, 2)).

    Returns ``(order, starts)``: ``order`` ((n,) int32) lists the particles colour by colour,
    colour c holding ``order[starts[c]:starts[c + 1]]``; no two particles of one colour share a
    spring, so a colour's vertices can be solved in parallel. At most D + 1 colours (D the
    largest number of springs at a particle); 9 to 10 on the 12-neighbour cloth grid.
    """
    ends = np.asarray(ends, dtype=np.int64).reshape(-1, 2)
    if len(ends) and np.any(ends[:, 0] == ends[:, 1]):
        raise ValueError("ends: a spring joins a particle to itself")
    both = np.concatenate([ends, ends[:, ::-1]]) if len(ends) else np.zeros((0, 2), np.int64)
    both = both[np.argsort(both[:, 0], kind="stable")]
    offsets = np.searchsorted(both[:, 0], np.arange(particle_count + 1))
    neighbours = both[:, 1].tolist()
    colours = [-1] * particle_count
    for i in range(particle_count):  # once, when the integrator is bound
        taken = 0
        for j in neighbours[offsets[i]:offsets[i + 1]]:
            if colours[j] >= 0:
                taken |= 1 << colours[j]
        colours[i] = (~taken & (taken + 1)).bit_length() - 1  # lowest free colour
    colour = np.asarray(colours, dtype=np.int64)
    order = np.argsort(colour, kind="stable").astype(np.int32)
    count = int(colour.max()) + 1 if particle_count else 0
    starts = np.searchsorted(colour[order], np.arange(count + 1)).tolist()
    return order, starts


def element_pairs(elements: np.ndarray) -> np.ndarray:
    """Every pair of vertices that share an element: (P, 2) int64, each pair once with the
    lower id first, from ``elements`` ((E, k) vertex ids: triangles, bending stencils). Given to
    :func:`colour_vertices` as springs, they keep an element's vertices in different colours,
    so no two vertices of a colour read each other's position in their solves."""
    elements = np.asarray(elements, dtype=np.int64)
    if elements.ndim != 2 or elements.shape[1] < 2:
        return np.zeros((0, 2), np.int64)
    k = elements.shape[1]
    first, second = np.triu_indices(k, 1)
    pairs = np.stack([elements[:, first].ravel(), elements[:, second].ravel()], axis=1)
    pairs = np.sort(pairs, axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    return np.unique(pairs, axis=0) if len(pairs) else pairs
