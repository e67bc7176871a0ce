"""Offscreen recording: step a Session, render each frame without a window, write a video."""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm import tqdm

from ..errors import ConfigError
from ..render.chart import Rect
from ..render.drawer import DRAWABLE_LIMIT
from ..render.overlay import WARNING, Label, burn
from ..render.renderer import Renderer
from ..render.video import MAX_SIDE, VideoWriter, check_output, save_png
from ..render.vulkan import open_window, take_back_imgui_ini
from .contacts_view import ContactsView
from .energy import curves_of
from .energy_view import EnergyView, panel_centres
from .session import Session

MAX_SECONDS = 3600.0
CHART_AREA = Rect(0.03, 0.09, 0.97, 0.30)  # the energy charts (normalised, y up)
LEGEND = Rect(0.935, 0.40, 0.955, 0.78)  # the strain colour bar


@dataclass(frozen=True)
class Clip:
    """What to record.

    Attributes:
        scene: preset name; params: its parameter overrides; seed: its random seed.
        integrators: one name, or two or three drawn side by side (same scene, same step).
        dt: step size (s); None: the preset's.
        seconds: video length (s); fps: video frames per second.
        size: (width, height) of the video in pixels.
        speed: simulated seconds per video second (each frame advances speed / fps s of
            simulated time, in steps of dt).
        supersample: render at this multiple of ``size`` and average down (smoother edges).
        colors: palette size of a GIF.
        curves: parameter name -> :class:`~taichi_sim.curves.Spline` driving it over time.
        integrator_options: integrator name -> its keyword options (e.g. a scene file's
            ``[integrator]`` table), used wherever that method runs.
        energy: plot each run's energy under its panel (scenes with an energy).
        strain: colour the cloth by spring strain, with a colour bar (scenes with a cloth).
        contacts: draw the contacts each run's solve holds (``vbd``; the launcher's ``x``).
        fit: frame what the run draws rather than the scene's start-up box: the video's camera
            is fixed on the box its points fill over the whole clip, the still's on their box at
            the still's time (so a cloth that folds onto the ground fills the still). The clip is
            simulated once more, ahead, to find the boxes. One integrator only.
    """

    scene: str
    integrators: tuple[str, ...]
    params: dict = field(default_factory=dict)
    dt: float | None = None
    seconds: float = 4.0
    fps: float = 30.0
    size: tuple[int, int] = (1280, 720)
    speed: float = 1.0
    seed: int = 0
    supersample: int = 1
    colors: int = 128
    curves: dict = field(default_factory=dict)
    integrator_options: dict = field(default_factory=dict)
    energy: bool = False
    strain: bool = False
    contacts: bool = False
    fit: bool = False

    @property
    def frame_count(self) -> int:
        return max(1, round(self.seconds * self.fps))


@dataclass(frozen=True)
class Recording:
    """What :func:`record` did: the output ``path``, ``frames`` written, ``wall`` seconds spent,
    the ``still`` PNG (or None), one line per run that stopped early (``failures``), and whether
    the recording itself stopped early because every run had (``stopped``: it then ends a
    second after the last one stopped, on its message). ``provenance``: what it was recorded
    from (:func:`provenance`; with the still's time and step when there is a still)."""

    path: Path
    frames: int
    wall: float
    still: Path | None
    failures: tuple[str, ...]
    stopped: bool = False
    provenance: dict = field(default_factory=dict)


#: The PNG text chunk (tEXt) a still carries its :func:`provenance` in, as JSON.
PNG_TEXT_KEY = "taichi-sim"


def provenance(clip: Clip, session: Session) -> dict:
    """What a recording of ``clip`` shows, as plain JSON values: the scene, the integrators, the
    step ``dt`` (s) and each method's options as the session runs them (the scene's own
    defaults included), the scene's default ``tolerance`` (m, or None), the parameters given
    (``params``; the rest are the preset's defaults), the seed, and the time ``t`` (s, the
    furthest run's) and ``steps`` (panel 0's) reached so far."""
    runners = session.runners
    scene = runners[0].scene
    names = [r.name for r in runners]
    return {
        "scene": session.scene_name,
        "integrators": names,
        "dt": float(session.dt),
        "integrator_options": {n: {**scene.options_for(n), **clip.integrator_options.get(n, {})} for n in names},
        "tolerance": scene.default_tolerance,
        "params": {k: v.item() if hasattr(v, "item") else v for k, v in clip.params.items()},
        "seed": int(clip.seed),
        "t": float(max(r.t for r in runners)),
        "steps": int(runners[0].steps),
    }


def check_clip(clip: Clip) -> None:
    """Raise ConfigError for a clip that cannot be recorded (before any work is done)."""
    if not (math.isfinite(clip.seconds) and 0 < clip.seconds <= MAX_SECONDS):
        raise ConfigError(f"--seconds must be a number in (0, {MAX_SECONDS:g}], got {clip.seconds}")
    if not (math.isfinite(clip.speed) and clip.speed > 0):
        raise ConfigError(f"--speed must be a finite number > 0, got {clip.speed}")
    if clip.supersample < 1 or max(clip.size) * clip.supersample > MAX_SIDE:
        raise ConfigError(f"supersample {clip.supersample} x size {clip.size} exceeds {MAX_SIDE} pixels")
    if clip.fit and len(clip.integrators) > 1:
        raise ConfigError("fit frames one run: side by side the panels share the start-up frame")


def drawn_box(session: Session) -> tuple[np.ndarray, np.ndarray] | None:
    """The box (lo, hi), each (3,) m, around every drawable point of panel 0's last good
    positions, or None when none is drawable."""
    pts = np.asarray(session.runners[0].last_good, np.float64).reshape(-1, 3)
    with np.errstate(invalid="ignore"):
        pts = pts[np.all(np.abs(pts) <= DRAWABLE_LIMIT, axis=1)]
    return (pts.min(axis=0), pts.max(axis=0)) if len(pts) else None


def clip_box(session: Session, clip: Clip) -> tuple[np.ndarray, np.ndarray]:
    """Simulate ``clip`` ahead as :func:`record` will, then reset the session to t = 0: the
    box (lo, hi), each (3,) m, the drawn points fill over every frame. (The still is framed on
    the recorded run itself: a run after a reset need not repeat the first to the bit, and
    cloth-spin's cloth left the sphere elsewhere the second time.)"""
    boxes = []
    for k in range(clip.frame_count):
        if k:
            session.advance(clip.speed / clip.fps)
        boxes.append(drawn_box(session))
        if session.frozen:  # record stops a second later; what it draws no longer moves
            break
    session.reset()
    found = [b for b in boxes if b is not None]
    if not found:
        raise ConfigError(f"fit: scene {clip.scene!r} draws no finite point to frame")
    return np.min([b[0] for b in found], axis=0), np.max([b[1] for b in found], axis=0)


def frame_labels(session: Session, renderer: Renderer, size: tuple[int, int]) -> list[Label]:
    """Text for one frame of ``size`` pixels: each panel's integrator above it (side by side),
    a caption with the scene, step and time, and why a run stopped."""
    width, height = size
    labels: list[Label] = []
    runners = session.runners
    line = max(11, round(height / 30)) * 1.5
    if len(runners) > 1:
        uv, depth = renderer.camera.project(np.array(renderer.label_points()))
        for r, (u, v), d in zip(runners, uv, depth):
            if d <= 0:
                continue
            x = float(np.clip(u * width, 0.1 * width, 0.9 * width))
            y = float(np.clip((1.0 - v) * height - 0.3 * line, line, height - 2 * line))
            labels.append(Label(r.name, x, y))
            if r.frozen:
                labels.append(Label(f"{r.status.value.replace('_', ' ')} at t = {r.failed_at:.3g} s",
                                    x, y + line, WARNING, anchor="mt"))
    t = max(r.t for r in runners)  # runs that froze stopped their clocks
    names = " vs ".join(r.name for r in runners)
    labels.append(Label(f"{session.scene_name}   {names}   h = {session.dt:.3g} s   t = {t:.2f} s",
                        0.5 * line, height - 0.4 * line, anchor="lb"))
    if len(runners) == 1 and runners[0].frozen:
        labels.append(Label(runners[0].message, 0.5 * line, height - 1.4 * line, WARNING, anchor="lb"))
    return labels


def record(clip: Clip, out: str | Path, *, still: str | Path | None = None, still_at: float = 1.0,
           progress: bool | None = None, warn=None) -> Recording:
    """Record ``clip`` into ``out`` (.mp4, .gif or a folder/ of PNGs) through the renderer,
    offscreen. Frame 0 is the initial state; each later frame advances the simulation by
    ``clip.speed / clip.fps`` seconds. ``still`` also saves the frame at fraction ``still_at``
    of the clip as a PNG at the rendering (supersampled) resolution. When every run has stopped
    (diverged, not converged, stiff), the recording holds the message for a second and ends.

    Validates everything before stepping; raises ConfigError for bad input and
    :class:`~taichi_sim.render.RenderUnavailable` when no Vulkan is usable. Needs
    :func:`taichi_sim.init`. Nothing partial is left on disk on failure. ``warn`` (a callable
    taking a line) hears, before the first frame, what the built scene warns of
    (:meth:`~taichi_sim.scene.scene.Scene.start_warning`).
    """
    check_clip(clip)
    check_output(out, clip.size, clip.fps)
    start = time.perf_counter()
    session = Session(clip.scene, clip.integrators, params=clip.params, dt=clip.dt, seed=clip.seed,
                      integrator_options=clip.integrator_options)
    start_warning = session.scenes[0].start_warning() if warn is not None else ""
    if start_warning:
        warn(start_warning)
    if clip.curves:
        session.set_curves(clip.curves)
    session.options.strain = clip.strain
    session.options.energy = clip.energy
    session.options.contacts = clip.contacts
    contacts = ContactsView()  # gathers nothing unless clip.contacts
    charts = clip.energy and bool(curves_of(session.runners[0].scene))  # the circle ODE has none
    view = EnergyView(CHART_AREA, LEGEND)
    strain_scale = (session.options.strain_scale if clip.strain and session.options.mesh
                    and session.visuals()[0].mesh is not None else None)
    ss = int(clip.supersample)
    render_size = (clip.size[0] * ss, clip.size[1] * ss)
    window = open_window(f"taichi-sim record {clip.scene}", render_size)
    still_index = min(clip.frame_count - 1, max(0, round(still_at * (clip.frame_count - 1))))
    still_path = None
    try:
        renderer = Renderer(window, session.visuals(), render_size,
                            bottom=CHART_AREA.y1 + 0.02 if charts else 0.0)
        if clip.fit:
            renderer.camera.frame(*clip_box(session, clip))
        with VideoWriter(out, clip.size, clip.fps, colors=clip.colors) as writer, \
                tqdm(total=clip.frame_count, unit="frame", leave=False, disable=None if progress is None
                     else not progress, desc=Path(out).name) as bar:
            held = 0
            for k in range(clip.frame_count):
                if k:
                    session.advance(clip.speed / clip.fps)
                if session.frozen:  # every run stopped: hold the message a second, then stop
                    held += 1
                    if held > clip.fps:
                        break
                if not clip.fit:
                    renderer.follow([r.last_good for r in session.runners])

                def draw() -> np.ndarray:
                    view.update(session.runners, panel_centres(renderer), energy=session.options.energy,
                                strain_scale=strain_scale)
                    contacts.update(session.runners, renderer, on=clip.contacts)
                    renderer.render([r.display for r in session.runners], session.options, overlay=view.draw,
                                    extras=contacts.draw)
                    return renderer.read_image()

                image = draw()
                frame = image if ss == 1 else np.asarray(
                    Image.fromarray(image).resize(clip.size, Image.Resampling.BOX))
                writer.append(burn(frame, frame_labels(session, renderer, clip.size) + view.labels(clip.size)))
                if still is not None and k == still_index:
                    shown = provenance(clip, session)
                    still_box = drawn_box(session) if clip.fit else None
                    if still_box is not None:  # the still framed on itself, then back
                        pose = renderer.camera.target.copy(), renderer.camera.distance
                        renderer.camera.frame(*still_box)
                        image = draw()
                        renderer.camera.target, renderer.camera.distance = pose
                    still_path = save_png(burn(image, frame_labels(session, renderer, render_size)
                                               + view.labels(render_size)), still,
                                          text={PNG_TEXT_KEY: json.dumps(shown, sort_keys=True)})
                bar.update()
                frames = k + 1
        path = writer.path
    except BaseException:
        if still_path is not None:
            still_path.unlink(missing_ok=True)
        raise
    finally:
        window.destroy()
        take_back_imgui_ini()
    failures = tuple(f"{r.name}: {r.message}" for r in session.runners if r.frozen)
    return Recording(path=path, frames=frames, wall=time.perf_counter() - start,
                     still=still_path, failures=failures, stopped=session.frozen,
                     provenance=shown if still_path is not None else {**provenance(clip, session), "t": None,
                                                                       "steps": None})
