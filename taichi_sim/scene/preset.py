"""ScenePreset: a named scene recipe with typed parameters."""
from dataclasses import dataclass, field, replace
from typing import Any, Callable

from ..memory import Size
from .builder import SceneBuilder
from .params import Param
from .scene import Scene


@dataclass(frozen=True)
class ScenePreset:
    """A scene recipe: ``build(preset, values, seed)`` returns a Scene; ``size(values)`` says, from
    the parameters alone, how many particles, springs and triangles it will allocate, and
    ``size_params`` which parameters decide that (named when a size is refused);
    ``integrator_options``: integrator name -> the keyword options the scene runs that method
    with unless told otherwise (:attr:`Scene.integrator_options`)."""

    name: str
    description: str
    params: tuple[Param, ...]
    build: Callable[["ScenePreset", dict[str, Any], int], Scene]
    default_dt: float
    default_integrator: str
    size: Callable[[dict[str, Any]], Size] = lambda values: Size(1, 0)
    size_params: tuple[str, ...] = ()
    explicit_dt: float | None = None  # s: an explicit method's step when not told (Scene.explicit_dt)
    integrator_options: dict[str, dict[str, Any]] = field(default_factory=dict, hash=False)
    default_tolerance: float | None = None  # m: the scene's --tolerance when not told (Scene.default_tolerance)

    def options_for(self, integrator: str) -> dict[str, Any]:
        """The keyword options this scene runs ``integrator`` with unless told otherwise (a
        new dict; empty for most)."""
        return dict(self.integrator_options.get(integrator, {}))

    def param(self, name: str) -> Param:
        return next(p for p in self.params if p.name == name)

    def finish(self, builder: SceneBuilder, values: dict[str, Any], seed: int, *,
               gravity: float | None = None, drag: float | None = None) -> Scene:
        """Add gravity (``values["gravity"]`` unless ``gravity`` (m/s^2, pointing -y) says
        otherwise) and drag (``values["drag"]`` unless ``drag``, N s/m a particle, says
        otherwise) and finalize."""
        builder.set_gravity(values["gravity"] if gravity is None else gravity)
        builder.set_drag(values["drag"] if drag is None else drag)
        return builder.finalize(name=self.name, params=values, default_dt=self.default_dt,
                                default_integrator=self.default_integrator, seed=seed,
                                integrator_options=self.integrator_options)


def common_params(*, mass: float, gravity: float = 9.8, drag: float = 0.0,
                  damping: float | None = 0.0) -> tuple[Param, ...]:
    """particle_mass, gravity, drag (and the spring dashpot ``damping`` unless None)."""
    params = (
        Param("particle_mass", mass, "kg", "mass of each particle", minimum=0.0, exclusive=True),
        Param("gravity", gravity, "m/s^2", "gravitational acceleration (pointing -y)"),
        Param("drag", drag, "N s/m", "viscous drag coefficient, force -drag * v", minimum=0.0),
    )
    if damping is not None:
        params += (Param("damping", damping, "N s/m", "spring dashpot coefficient along the spring",
                         minimum=0.0),)
    return params


def with_defaults(params: tuple[Param, ...], **defaults) -> tuple[Param, ...]:
    """The same parameters with some defaults changed (for presets that share a family)."""
    unknown = set(defaults) - {p.name for p in params}
    if unknown:
        raise KeyError(f"no such parameters: {sorted(unknown)}")
    return tuple(replace(p, default=defaults[p.name]) if p.name in defaults else p for p in params)
