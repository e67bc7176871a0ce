"""Apply curves to a running scene as time advances (at step granularity).

Before each step from t, every driven parameter takes its curve's value at t, through the same
live setters the launcher's sliders use (:mod:`taichi_sim.scene.live`). The emitter's rate is
the exception: the emitter integrates the rate curve exactly over each step, so a run emits
the integral of the curve (to within the one particle its carried fraction holds back).
"""
from __future__ import annotations

import math

from ..errors import ConfigError
from ..scene.live import EVENT_PARAMS, LIVE_SETTERS, applies_live
from ..scene.scene import Scene
from .files import Curves

#: A force parameter is written again only when its curve moved by more than this fraction of
#: the curve's range since the last write: each write resets the integrator (FSAL, warm starts)
#: and re-bases the blow-up guard, which should not happen at every step of a slow ramp.
FORCE_RESOLUTION = 1e-3


class CurveDriver:
    """Drives ``scene``'s parameters along ``curves`` (name -> Spline).

    Raises ConfigError when a curve names a parameter this scene cannot change while it runs
    (e.g. ``wind_speed`` on a scene built without wind).
    """

    def __init__(self, scene: Scene, curves: Curves):
        for name in curves:
            if not applies_live(scene, name):
                raise ConfigError(f"curve {name}: scene {scene.name!r} as built cannot change {name!r} "
                                  f"while it runs (is the feature it tunes switched on?)")
        self.scene = scene
        self.curves = dict(curves)
        self.values = dict(scene.params)
        self._written: dict[str, float] = {}
        self._span = {name: (max(s.values) - min(s.values)) for name, s in self.curves.items()}
        if scene.emitter is not None:
            scene.emitter.rate_curve = self.curves.get("rate")

    def detach(self) -> None:
        """Stop driving: the emitter goes back to its constant rate."""
        if self.scene.emitter is not None:
            self.scene.emitter.rate_curve = None

    def apply(self, t: float) -> bool:
        """Set every driven parameter to its curve's value at time t (s). Returns True when a
        force changed (the caller resets its integrator and re-bases its guard)."""
        forces_changed = False
        for name, spline in self.curves.items():
            value = spline(t)
            kind = type(self.scene.params[name])
            if kind is int:
                value = int(round(value))
            last = self._written.get(name)
            if name in EVENT_PARAMS:
                if last == value:
                    continue
            elif last is not None and abs(value - last) <= FORCE_RESOLUTION * self._span[name]:
                continue
            if not math.isfinite(value):
                continue
            self.values[name] = value
            LIVE_SETTERS[name](self.scene, self.values)
            self._written[name] = value
            forces_changed |= name not in EVENT_PARAMS
        return forces_changed

    def restart(self) -> None:
        """Forget what was written (after the scene was restored to t = 0)."""
        self._written.clear()
        self.values = dict(self.scene.params)
        if self.scene.emitter is not None:
            self.scene.emitter.rate_curve = self.curves.get("rate")
