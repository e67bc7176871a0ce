"""The showcase: a short GIF and a still PNG per entry of a table, recorded offscreen.

``taichi-sim record --showcase [DIR]`` records it (into media/ by default: the README's gallery)
and writes what each entry was recorded from into ``DIR/gallery.json`` (:data:`MANIFEST`);
``--only NAME,...`` re-records some entries and updates theirs. ``taichi-sim`` with no display
records the short :data:`QUICK_SHOWCASE` into out/showcase/. To add a scene to the showcase, add
a row to :data:`SHOWCASE`.

An entry runs its preset as the preset is (its default integrator and step, read from the preset
when this module is imported) unless it is ``chosen``: a demonstration of other settings (explicit
Euler spiralling out, three methods side by side). tests/test_gallery.py compares the manifest
with the presets, so a preset whose default changes fails until its entry is re-recorded.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path

from ..atomic import write_atomically
from ..errors import ConfigError
from ..scene import scene_preset
from .record import Clip, Recording, record

GIF_SIZE = (480, 320)  # pixels; stills are rendered at twice the GIF size (GIFs supersampled)
GIF_FPS = 12.0
GIF_SECONDS = 4.0


@dataclass(frozen=True)
class Showcase:
    """One showcase entry: ``name`` is the file stem (``name.gif``, ``name.png``), ``title`` a
    line saying what it shows, ``clip`` what to record, ``still_at`` the fraction of the clip
    whose frame becomes the still, ``chosen`` whether the clip's integrators and step are chosen
    to show something (else they are the preset's defaults)."""

    name: str
    title: str
    clip: Clip
    still_at: float = 0.75
    chosen: bool = False


MANIFEST = "gallery.json"  # what each entry of a recorded showcase was recorded from


def _clip(scene: str, integrators=None, *, params=None, dt=None, speed: float = 1.0,
          size: tuple[int, int] = GIF_SIZE, fit: bool = False) -> Clip:
    """A showcase clip; without ``integrators`` the preset's default integrator (and, without
    ``dt``, its step)."""
    integrators = (scene_preset(scene).default_integrator,) if integrators is None else tuple(integrators)
    return Clip(scene=scene, integrators=integrators, params=dict(params or {}), dt=dt,
                seconds=GIF_SECONDS, fps=GIF_FPS, size=size, speed=speed, supersample=2, colors=96, fit=fit)


SHOWCASE: tuple[Showcase, ...] = (
    Showcase("cloth", "a 24x24 cloth pinned at two corners falls and folds",
             _clip("cloth", params={"nx": 24, "ny": 24}, fit=True)),
    Showcase("pendulum", "a chain of five particles on stiff springs swings from its pin",
             _clip("pendulum")),
    Showcase("simple-trail", "the circle ODE with explicit Euler at h = 0.1: the orbit spirals "
             "outward from the exact circle", _clip("simple", ["euler"], dt=0.1, speed=4.0), chosen=True),
    Showcase("integrators", "the pendulum chain at h = 8 ms with explicit Euler (diverges and "
             "freezes), RK4 and symplectic Euler (both stable)",
             _clip("pendulum", ["euler", "rk4", "symplectic_euler"], dt=8e-3, size=(640, 300)), chosen=True),
    Showcase("cloth-sphere", "a cloth drops onto a sphere above the ground",
             _clip("cloth-sphere", params={"nx": 24, "ny": 24}, fit=True)),
    Showcase("cloth-spin", "a cloth dropped onto a spinning sphere: friction drags it round until "
             "it slides off, without passing through itself (self-collision)",
             _clip("cloth-spin", params={"nx": 24, "ny": 24}, fit=True)),
    Showcase("cloth-tear", "a sphere drops through a cloth held at two sides and tears it",
             _clip("cloth-tear", fit=True)),
    Showcase("cloth-fold", "a cloth dropped edge-first falls over and folds onto itself without "
             "passing through itself (self-collision)",
             _clip("cloth-fold", params={"nx": 24, "ny": 24}, fit=True)),
    Showcase("cloth-twist", "a cloth held at two sides that turn in opposite directions wrings "
             "into folds against itself (self-collision)",
             _clip("cloth-twist", params={"nx": 24, "ny": 24}, fit=True)),
    Showcase("cloth-wind", "a flag on a pole in gusty wind: the two sides in two colours",
             _clip("cloth-wind", params={"nx": 24, "ny": 24})),
    Showcase("garment", "a skirt sewn from ten flat panels (5 000 vertices), pinned at the waist, "
             "drapes in folds over hips and legs",
             _clip("garment")),
    Showcase("sprinkler", "a sprinkler: drops that darken and fade with age bounce on the ground",
             _clip("sprinkler")),
    Showcase("sprinkler-fire", "a burner: buoyant, turbulent flames cool from yellow to red, "
             "shrink and fade", _clip("sprinkler-fire")),
    Showcase("sprinkler-smoke", "a smoke plume: slow grey puffs rise, grow and thin out",
             _clip("sprinkler-smoke", speed=1.5)),
)


#: A short showcase (what ``taichi-sim`` records without a display): four of the entries, 2 s
#: each, without supersampling: about 30 s of CPU time in all (the full table: 5 to 15 minutes).
QUICK_SECONDS = 2.0
QUICK_SHOWCASE: tuple[Showcase, ...] = tuple(
    replace(entry, clip=replace(entry.clip, seconds=QUICK_SECONDS, supersample=1))
    for entry in SHOWCASE if entry.name in ("cloth", "integrators", "cloth-sphere", "sprinkler-fire"))


def select(names: str | None, entries: tuple[Showcase, ...] = SHOWCASE) -> tuple[Showcase, ...]:
    """The entries named in ``names`` (comma-separated, e.g. ``"cloth-fold,cloth-spin"``), in
    the table's order; all of ``entries`` for None. ConfigError names an unknown one."""
    if names is None:
        return entries
    wanted = [n.strip() for n in names.split(",") if n.strip()]
    known = {e.name for e in entries}
    unknown = [n for n in wanted if n not in known]
    if unknown or not wanted:
        raise ConfigError(f"--only: no showcase entry {', '.join(unknown) or repr(names)} "
                          f"(choose from {', '.join(e.name for e in entries)})")
    return tuple(e for e in entries if e.name in wanted)


def manifest_item(entry: Showcase, recording: Recording) -> dict:
    """The manifest's record of ``entry`` as recorded: its files, title and settings (the clip's
    length, rate, size, speed, framing and still fraction), with the recording's
    :func:`~taichi_sim.app.record.provenance` (scene, integrators, dt, options, parameters given,
    the still's time ``t`` and ``steps``)."""
    clip = entry.clip
    return {
        "name": entry.name, "title": entry.title, "gif": recording.path.name,
        "png": recording.still.name if recording.still is not None else None,
        "settings": "chosen" if entry.chosen else "preset",
        **recording.provenance,
        "seconds": clip.seconds, "fps": clip.fps, "size": list(clip.size), "speed": clip.speed,
        "supersample": clip.supersample, "fit": clip.fit, "still_at": entry.still_at,
        "frames": recording.frames, "failures": list(recording.failures),
    }


def read_manifest(folder: str | os.PathLike) -> dict[str, dict]:
    """The items of ``folder``'s :data:`MANIFEST` by name ({} where there is none)."""
    path = Path(folder) / MANIFEST
    if not path.exists():
        return {}
    return {item["name"]: item for item in json.loads(path.read_text())["items"]}


def _write_manifest(folder: Path, items: dict[str, dict]) -> None:
    order = {e.name: k for k, e in enumerate(SHOWCASE)}
    ordered = sorted(items.values(), key=lambda item: (order.get(item["name"], len(order)), item["name"]))
    text = json.dumps({"recorded_by": "taichi-sim record --showcase", "items": ordered}, indent=1) + "\n"
    write_atomically(folder / MANIFEST, lambda f: f.write(text), binary=False)


#: The clip settings an item records as the table gives them.
_CLIP_KEYS = ("scene", "params", "seed", "seconds", "fps", "speed", "supersample", "fit")


def expected_settings(entry: Showcase) -> dict:
    """What recording ``entry`` runs, read from its preset as it is (nothing is built): its
    ``integrators`` (the preset's default; a ``chosen`` entry: its clip's), step ``dt`` (s; the
    preset's ``default_dt``, a chosen entry's own), each method's ``integrator_options`` (the
    preset's, under the clip's) and the preset's ``tolerance`` (m or None). A recording at
    another step than the preset's default (a fine grid's shorter explicit stable step) reads
    as stale: the gallery shows each preset at its default step."""
    clip = entry.clip
    preset = scene_preset(clip.scene)
    names = list(clip.integrators) if entry.chosen else [preset.default_integrator]
    return {
        "integrators": names,
        "dt": float(clip.dt if entry.chosen and clip.dt is not None else preset.default_dt),
        "integrator_options": {n: {**preset.options_for(n), **clip.integrator_options.get(n, {})} for n in names},
        "tolerance": preset.default_tolerance,
    }


def stale_items(items: dict[str, dict], entries: tuple[Showcase, ...] = SHOWCASE) -> list[str]:
    """One line per way the recorded ``items`` (a manifest's, by name: :func:`read_manifest`)
    differ from what ``entries`` record now: an entry not recorded, an item no entry makes, a
    clip setting changed, a preset entry whose clip is not its preset's defaults, and the
    integrators, step, options or tolerance the presets now give ([] when the gallery is
    current). Reads the presets only: fast, no Taichi runtime."""
    lines = [f"{name}: recorded, but no showcase entry makes it" for name in items if name not in
             {e.name for e in entries}]
    for entry in entries:
        item = items.get(entry.name)
        if item is None:
            lines.append(f"{entry.name}: not recorded")
            continue
        clip = entry.clip
        preset = scene_preset(clip.scene)
        if not entry.chosen and (list(clip.integrators) != [preset.default_integrator] or clip.dt is not None):
            lines.append(f"{entry.name}: not chosen, yet its clip runs {', '.join(clip.integrators)} at dt "
                         f"{clip.dt} (the preset: {preset.default_integrator} at its own step)")
        wanted = {**{k: getattr(clip, k) for k in _CLIP_KEYS}, "size": list(clip.size),
                  "still_at": entry.still_at, "settings": "chosen" if entry.chosen else "preset",
                  **expected_settings(entry)}
        for key, value in wanted.items():
            if item.get(key) != value:
                lines.append(f"{entry.name}: recorded with {key} = {item.get(key)!r}, now {value!r}")
    return lines


def record_showcase(folder: str | os.PathLike, *, progress: bool | None = None,
                    entries: tuple[Showcase, ...] = SHOWCASE, on_clip=None) -> list[Recording]:
    """Record every entry into ``folder`` (created if missing; its parent must exist) as
    ``NAME.gif`` plus ``NAME.png``, and after each one update ``folder``'s :data:`MANIFEST`
    (the items of entries not recorded now are kept). ``on_clip(k, count, entry, recording)``,
    when given, is called after each (k from 1). Needs :func:`taichi_sim.init`. A folder this
    call created is removed again if the recording fails before anything is written into it."""
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
            items = read_manifest(folder)
            items[entry.name] = manifest_item(entry, recordings[-1])
            _write_manifest(folder, items)
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
