"""Parameters that change on a running scene without rebuilding it (the launcher's live
sliders, and curves that drive parameters over time).

A setter ``setter(scene, values) -> bool`` writes ``values[name]`` into the running scene and
returns False when the scene lacks what the parameter tunes (a scene built with zero drag has
no drag term: changing drag then needs a rebuild). :func:`applies_live` says in advance.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable

from .cloth import KIND_STIFFNESS_PARAMS, grid_particle_drag, kind_stiffness
from .scene import Scene


def _set_spring_stiffness(scene: Scene, p: dict) -> bool:
    springs = scene.springs
    if springs is None:
        return False
    if "flex_stiffness" in p:  # a cloth, grid or mesh (no shear springs): one stiffness per kind
        k = kind_stiffness(springs.kind_np, [p["stiffness"], p.get("shear_stiffness", p["stiffness"]),
                                             p["flex_stiffness"]])
    else:
        k = p["stiffness"]
    springs.set_parameters(stiffness=k)
    return True


def _set_damping(scene: Scene, p: dict) -> bool:
    if scene.springs is None or not scene.springs.damped:  # dashpots were compiled away
        return False
    scene.springs.set_parameters(damping=p["damping"])
    return True


def _term_setter(term: str, apply: Callable[[Any, dict], None]) -> Callable[[Scene, dict], bool]:
    def setter(scene: Scene, p: dict) -> bool:
        found = scene.system.term(term) if hasattr(scene.system, "term") else None
        if found is None:
            return False
        apply(found, p)
        return True
    return setter


def _emitter_setter(name: str) -> Callable[[Scene, dict], bool]:
    # The emitter reads its spec in Python at every launch: replacing it is the whole change.
    def setter(scene: Scene, p: dict) -> bool:
        if scene.emitter is None:
            return False
        scene.emitter.spec = replace(scene.emitter.spec, **{name: float(p[name])})
        return True
    return setter


def _set_sphere_speed(scene: Scene, p: dict) -> bool:
    if scene.spheres is None or p.get("sphere_motion") not in ("drop", "sweep"):
        return False
    scene.spheres.set_speed(p["sphere_speed"])
    return True


def _set_drag(scene: Scene, p: dict) -> bool:
    """The drag term's coefficient a particle (N s/m): ``drag``, or on the grid cloth
    ``area_drag`` times each particle's share of the area."""
    term = scene.system.term("drag") if hasattr(scene.system, "term") else None
    if term is None or not ("drag" in p or "area_drag" in p):
        return False
    term.set(grid_particle_drag(p) if "area_drag" in p else p["drag"])
    return True


def _set_gain(scene: Scene, p: dict) -> bool:
    if scene.constraints is None:
        return False
    scene.constraints.set_gains(p["ks"], p["kd"])
    return True


#: name -> setter, for every parameter that can change while a scene runs.
LIVE_SETTERS: dict[str, Callable[[Scene, dict], bool]] = {
    "stiffness": _set_spring_stiffness,
    "shear_stiffness": _set_spring_stiffness,
    "flex_stiffness": _set_spring_stiffness,
    "damping": _set_damping,
    "gravity": _term_setter("gravity", lambda t, p: t.set((0.0, p.get("buoyancy", 0.0) - p["gravity"], 0.0))),
    "drag": _set_drag,
    "area_drag": _set_drag,
    "wind": _term_setter("wind", lambda t, p: t.set(enabled=p["wind"])),
    "wind_speed": _term_setter("wind", lambda t, p: t.set(speed=p["wind_speed"])),
    "wind_heading": _term_setter("wind", lambda t, p: t.set(heading=p["wind_heading"])),
    "wind_gust": _term_setter("wind", lambda t, p: t.set(gust=p["wind_gust"])),
    "wind_drag": _term_setter("wind", lambda t, p: t.set(drag_coefficient=p["wind_drag"])),
    "rate": _emitter_setter("rate"),
    "speed": _emitter_setter("speed"),
    "spread": _emitter_setter("spread"),
    "lifetime": _emitter_setter("lifetime"),
    "sphere_speed": _set_sphere_speed,
    "ks": _set_gain,
    "kd": _set_gain,
}

#: Live parameters that only touch post-step events (the emitter, a sphere's path), not the
#: forces: changing them needs no integrator reset and no new guard reference.
EVENT_PARAMS = frozenset({"rate", "speed", "spread", "lifetime", "sphere_speed"})


def applies_live(scene: Scene, name: str) -> bool:
    """Whether parameter ``name`` can change on ``scene`` while it runs."""
    if name not in LIVE_SETTERS:
        return False
    if name in ("drag", "area_drag") and name not in scene.params:
        return False  # the grid cloth's drag is area_drag, any other scene's drag
    if name in KIND_STIFFNESS_PARAMS:
        return scene.springs is not None
    if name == "damping":
        return scene.springs is not None and scene.springs.damped
    if name in ("rate", "speed", "spread", "lifetime"):
        return scene.emitter is not None
    if name in ("ks", "kd"):
        return scene.constraints is not None
    if name == "sphere_speed":
        return scene.spheres is not None and scene.params.get("sphere_motion") in ("drop", "sweep")
    term = {"gravity": "gravity", "drag": "drag", "area_drag": "drag"}.get(name, "wind")
    return hasattr(scene.system, "term") and scene.system.term(term) is not None
