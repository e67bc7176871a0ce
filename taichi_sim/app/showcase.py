"""The showcase: a short GIF and a still PNG per entry of a table, recorded offscreen.

``taichi-sim record --showcase [DIR]`` records it (into media/ by default: the README's gallery);
``taichi-sim`` with no display records the short :data:`QUICK_SHOWCASE` into out/showcase/. To
add a scene to the showcase, add a row to :data:`SHOWCASE`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

from ..errors import ConfigError
from .record import Clip, Recording, record

GIF_SIZE = (480, 320)  # pixels; stills are rendered at twice the GIF size (GIFs supersampled)
GIF_FPS = 12.0
GIF_SECONDS = 4.0


@dataclass(frozen=True)
class Showcase:
    """One showcase entry: ``name`` is the file stem (``name.gif``, ``name.png``), ``title`` a
    line saying what it shows, ``clip`` what to record, ``still_at`` the fraction of the clip
    whose frame becomes the still."""

    name: str
    title: str
    clip: Clip
    still_at: float = 0.75


def _clip(scene: str, integrators, *, params=None, dt=None, speed: float = 1.0,
          size: tuple[int, int] = GIF_SIZE) -> Clip:
    return Clip(scene=scene, integrators=tuple(integrators), params=dict(params or {}), dt=dt,
                seconds=GIF_SECONDS, fps=GIF_FPS, size=size, speed=speed, supersample=2, colors=96)


SHOWCASE: tuple[Showcase, ...] = (
    Showcase("cloth", "a 24x24 cloth pinned at two corners falls and folds (symplectic Euler)",
             _clip("cloth", ["symplectic_euler"], params={"nx": 24, "ny": 24}, dt=1e-3)),
    Showcase("pendulum", "a chain of five particles on stiff springs swings from its pin",
             _clip("pendulum", ["symplectic_euler"], dt=1e-3)),
    Showcase("simple-trail", "the circle ODE with explicit Euler at h = 0.1: the orbit spirals "
             "outward from the exact circle", _clip("simple", ["euler"], dt=0.1, speed=4.0)),
    Showcase("integrators", "the pendulum chain at h = 8 ms with explicit Euler (diverges and "
             "freezes), RK4 and symplectic Euler (both stable)",
             _clip("pendulum", ["euler", "rk4", "symplectic_euler"], dt=8e-3, size=(640, 300))),
    Showcase("cloth-sphere", "a cloth drops onto a sphere above the ground",
             _clip("cloth-sphere", ["symplectic_euler"], params={"nx": 24, "ny": 24})),
    Showcase("cloth-spin", "a cloth dropped onto a spinning sphere: friction drags it round until "
             "it slides off, without passing through itself (self-collision)",
             _clip("cloth-spin", ["symplectic_euler"], params={"nx": 24, "ny": 24})),
    Showcase("cloth-tear", "a sphere drops through a cloth held at two sides and tears it",
             _clip("cloth-tear", ["symplectic_euler"])),
    Showcase("cloth-fold", "a cloth dropped edge-first piles up in folds without passing through "
             "itself (self-collision)",
             _clip("cloth-fold", ["symplectic_euler"], params={"nx": 24, "ny": 24})),
    Showcase("cloth-twist", "a cloth held at two sides that turn in opposite directions wrings "
             "into folds against itself (self-collision)",
             _clip("cloth-twist", ["symplectic_euler"], params={"nx": 24, "ny": 24})),
    Showcase("cloth-wind", "a flag on a pole in gusty wind: the two sides in two colours",
             _clip("cloth-wind", ["symplectic_euler"], params={"nx": 24, "ny": 24})),
    Showcase("garment", "a skirt sewn from ten flat panels (5 000 vertices), pinned at the waist, "
             "drapes in folds over hips and legs (XPBD at one step per frame)",
             _clip("garment", ["xpbd"])),
    Showcase("sprinkler", "a sprinkler: drops that darken and fade with age bounce on the ground",
             _clip("sprinkler", ["symplectic_euler"])),
    Showcase("sprinkler-fire", "a burner: buoyant, turbulent flames cool from yellow to red, "
             "shrink and fade", _clip("sprinkler-fire", ["symplectic_euler"])),
    Showcase("sprinkler-smoke", "a smoke plume: slow grey puffs rise, grow and thin out",
             _clip("sprinkler-smoke", ["symplectic_euler"], speed=1.5)),
)


#: A short showcase (what ``taichi-sim`` records without a display): four of the entries, 2 s
#: each, without supersampling: about 30 s of CPU time in all (the full table: 5 to 15 minutes).
QUICK_SECONDS = 2.0
QUICK_SHOWCASE: tuple[Showcase, ...] = tuple(
    replace(entry, clip=replace(entry.clip, seconds=QUICK_SECONDS, supersample=1))
    for entry in SHOWCASE if entry.name in ("cloth", "integrators", "cloth-sphere", "sprinkler-fire"))


def record_showcase(folder: str | os.PathLike, *, progress: bool | None = None,
                    entries: tuple[Showcase, ...] = SHOWCASE, on_clip=None) -> list[Recording]:
    """Record every entry into ``folder`` (created if missing; its parent must exist) as
    ``NAME.gif`` plus ``NAME.png``. ``on_clip(k, count, entry, recording)``, when given, is
    called after each (k from 1). Needs :func:`taichi_sim.init`. A folder this call created
    is removed again if the recording fails before anything is written into it."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"showcase folder {str(folder)!r} is not a directory")
    created = not folder.exists()
    if created:
        if not folder.parent.is_dir():
            raise ConfigError(f"cannot create {str(folder)!r}: {str(folder.parent)!r} does not exist")
        folder.mkdir()
    elif not os.access(folder, os.W_OK):
        raise ConfigError(f"cannot write into {str(folder)!r}: permission denied")
    try:
        recordings = []
        for k, entry in enumerate(entries, 1):
            recordings.append(record(entry.clip, folder / f"{entry.name}.gif", still=folder / f"{entry.name}.png",
                                     still_at=entry.still_at, progress=progress))
            if on_clip is not None:
                on_clip(k, len(entries), entry, recordings[-1])
        return recordings
    except BaseException:
        if created and not any(folder.iterdir()):
            folder.rmdir()
        raise


def shortened(entry: Showcase, seconds: float) -> Showcase:
    """``entry`` with a shorter clip (for quick checks)."""
    return replace(entry, clip=replace(entry.clip, seconds=seconds))
