"""The collider shape contract and its registry: what every analytic collider kind (plane,
sphere, capsule, box, and any kind a plug-in adds) tells the rest of the code once, in its own
file, so that `check`, the start warning and the solvers loop over the kinds instead of naming
them (docs/collisions.md, "Adding a collider shape").

A kind is its part class (one :class:`~taichi_sim.part.ScenePart` holding every object of the
kind), registered with :func:`register_shape` when its module is imported. The numpy side,
which this module's loops read from a run's npz keys alone:

- ``key``: the prefix of its npz keys (``sphere``: ``sphere_center``, ``sphere_radius``); the
  registry's key.
- ``size_keys``: the npz keys of its sizes, one row per object, which its part's ``arrays()``
  writes; ``moving``: whether it also writes ``{key}_center`` ((K, 3), m), and a run keeps
  ``{key}_center_history`` with its frames (False: a static object, the plane).
- ``noun`` (one object: the start warning, "6 inside the capsule") and ``label`` (the kind:
  `check`'s lines, "no vertex inside the capsules").
- ``point_depths(x, objects)``: ((N, K), m) how deep each point lies inside each object (negative
  outside), from ``objects`` (the npz keys above); ``thinnest_sizes(objects)``: ((K,), m) each
  object's thinnest size, which scales how deep a face may reach in, or None where faces are
  not judged (a flat plane is entered by a face only where a corner enters it).

The kernel side (the ``ti.func``s the post-step pass, the self-contact stage and vbd's solve
call per object) is :class:`~.obstacle.Obstacle`'s and :class:`~.faces.FaceContact`'s
contract; a translating kind inherits the post-step pass from
:class:`~.translating.TranslatingShapes`.
"""
from __future__ import annotations

import numpy as np

from ...geometry.inside import FACE_SHARE, INSIDE_TOLERANCE, face_samples

_SHAPES: dict[str, type] = {}


class Shape:
    """The numpy side of a collider kind (the module's docstring); a kind's part class
    subclasses it and is registered with :func:`register_shape`."""

    key: str
    size_keys: tuple[str, ...] = ()
    moving = True
    noun: str
    label: str

    @classmethod
    def npz_keys(cls) -> tuple[str, ...]:
        """Every npz key the kind's objects are judged from (the centres first, when moving)."""
        return ((f"{cls.key}_center",) if cls.moving else ()) + tuple(cls.size_keys)

    @classmethod
    def present(cls, arrays: dict) -> bool:
        """Whether ``arrays`` describes objects of this kind (all of :meth:`npz_keys`)."""
        return all(k in arrays for k in cls.npz_keys())

    @classmethod
    def point_depths(cls, x: np.ndarray, objects: dict) -> np.ndarray:
        """(N, K) float64: how deep each point of ``x`` ((N, 3), m) lies inside each object (m,
        negative outside)."""
        raise NotImplementedError

    @classmethod
    def thinnest_sizes(cls, objects: dict) -> np.ndarray | None:
        """(K,) float64: each object's thinnest size (m), or None: faces are not judged."""
        return None


def register_shape(cls: type) -> type:
    """Class decorator: put collider kind ``cls`` (a :class:`Shape`) in the registry that
    `check` and the start warning loop over. ValueError for a kind without what the contract
    asks, or a ``key`` another kind has."""
    missing = [name for name in ("key", "noun", "label") if not isinstance(getattr(cls, name, None), str)]
    if not issubclass(cls, Shape) or missing:
        raise ValueError(f"register_shape: {cls.__name__} must subclass Shape and name "
                         f"{', '.join(missing) or 'key, noun and label'} (see docs/collisions.md)")
    other = _SHAPES.get(cls.key)
    if other is not None and other.__qualname__ != cls.__qualname__:
        raise ValueError(f"register_shape: {cls.__name__}'s key {cls.key!r} is {other.__name__}'s already")
    _SHAPES[cls.key] = cls  # (a module imported again replaces its own kind)
    return cls


def shapes() -> list[type]:
    """The registered kinds, in the order of their parts' post-step events (``order``)."""
    return sorted(_SHAPES.values(), key=lambda cls: getattr(cls, "order", 50))


def shape(key: str) -> type:
    """The registered kind of npz key prefix ``key`` (KeyError if none)."""
    return _SHAPES[key]


def inside_objects(x: np.ndarray, arrays: dict, tolerance: float = INSIDE_TOLERANCE) -> dict[str, np.ndarray]:
    """Kind key -> (N,) bool mask of the points ``x`` ((N, 3), m) deeper than ``tolerance`` (m)
    inside any object of that kind (a vertex resting on a surface is not counted); only the
    kinds ``arrays`` (a run's npz keys, :attr:`Scene.arrays`) has."""
    x = np.asarray(x, np.float64).reshape(-1, 3)
    out = {}
    for kind in shapes():
        if kind.present(arrays):
            depth = kind.point_depths(x, arrays)
            out[kind.key] = (depth > tolerance).any(axis=1) if depth.shape[1] else np.zeros(len(x), bool)
    return out


def object_depths(x: np.ndarray, arrays: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Kind key -> ((N, K) how deep each point of ``x`` ((N, 3), m) lies inside each object of
    that kind (m; negative outside), (K,) each object's thinnest size (m)); the kinds
    ``arrays`` has whose faces are judged (not the plane)."""
    x = np.asarray(x, np.float64).reshape(-1, 3)
    out = {}
    for kind in shapes():
        if kind.present(arrays):
            thinnest = kind.thinnest_sizes(arrays)
            if thinnest is not None:
                out[kind.key] = (kind.point_depths(x, arrays).reshape(len(x), -1), np.asarray(thinnest, np.float64))
    return out


def face_depths(x: np.ndarray, triangles: np.ndarray, arrays: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Kind key -> ((T,) share, (T,) depth in m): for each triangle ((T, 3) ids into ``x``,
    (n, 3) m), how deep the deepest point of
    :func:`~taichi_sim.geometry.inside.face_samples` lies inside an object of that kind, as a
    share of that object's thinnest size and in metres (0 outside them all); the kinds of
    :func:`object_depths` that ``arrays`` has at least one object of."""
    triangles = np.asarray(triangles).reshape(-1, 3)
    points = face_samples(x, triangles)
    out = {}
    rows = np.arange(len(triangles))
    for key, (depth, thinnest) in object_depths(points.reshape(-1, 3), arrays).items():
        if depth.shape[1] == 0:
            continue  # no object of this kind
        # (T, P x K): every sample point of a triangle against every object of the kind
        share = (depth / thinnest[None]).reshape(len(triangles), -1)
        deepest = np.argmax(share, axis=1)
        out[key] = (np.maximum(share[rows, deepest], 0.0),
                    np.maximum(depth.reshape(len(triangles), -1)[rows, deepest], 0.0))
    return out


def faces_inside(x: np.ndarray, triangles: np.ndarray, arrays: dict, share: float = FACE_SHARE) -> dict[str, np.ndarray]:
    """Kind key -> (T,) bool mask of the triangles ((T, 3) ids into ``x``, (n, 3) m) with a
    point of :func:`~taichi_sim.geometry.inside.face_samples` deeper inside an object of that
    kind than ``share`` of the object's thinnest size (:func:`face_depths`)."""
    return {key: shares > share for key, (shares, _) in face_depths(x, triangles, arrays).items()}


def rows(a) -> np.ndarray:
    """``a`` as (K, 3) float64 rows (an npz's per-object vectors)."""
    return np.asarray(a, np.float64).reshape(-1, 3)
