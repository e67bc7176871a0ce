"""Opening a GGUI window, or saying in one line why none can be opened.

GGUI renders with Vulkan. On a headless Linux machine Mesa's software driver (Debian package
``mesa-vulkan-drivers``) is enough for offscreen rendering; an on-screen window also needs a
display (``DISPLAY`` or ``WAYLAND_DISPLAY``).

Keep one window open at a time: in Taichi 1.7.4, closing (or garbage-collecting) a GGUI window
breaks every other window still open, and a window must be closed before ``ti.init`` runs again.
"""
from __future__ import annotations

import atexit
import contextlib
import glob
import os
import platform
import sys
from pathlib import Path

INSTALL_HINT = ("install a Vulkan driver, e.g. on Debian/Ubuntu `sudo apt-get install "
                "mesa-vulkan-drivers` (Mesa's software renderer works without a GPU)")
ICD_DIRS = ("/usr/share/vulkan/icd.d", "/usr/local/share/vulkan/icd.d", "/etc/vulkan/icd.d",
            os.path.expanduser("~/.local/share/vulkan/icd.d"))


class RenderUnavailable(RuntimeError):
    """No window can be opened here; the message is one line saying what is missing."""


def has_display() -> bool:
    """Whether an on-screen window can be shown (an X11 or Wayland display is set)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _icd_files() -> list[str]:
    return [f for d in ICD_DIRS for f in glob.glob(os.path.join(d, "*.json"))]


@contextlib.contextmanager
def _quiet_stderr():
    """Silence file descriptor 2 (the Vulkan loader and Taichi's C++ layer print there)."""
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


#: ImGui (inside GGUI) saves its window layout to this file in the current directory, when a
#: window closes, even an offscreen one; Taichi offers no way to turn that off.
IMGUI_INI = "imgui.ini"

#: imgui.ini paths a window was opened beside -> their content before (None: there was none).
_INI_BEFORE: dict[Path, bytes | None] = {}


def watch_imgui_ini(path: Path | None = None) -> Path:
    """Note what ``path`` (default: ``imgui.ini`` in the current directory) holds before ImGui
    may write it (once per process and path), and make sure it is taken back at exit even when
    the window is destroyed by someone else."""
    path = Path.cwd() / IMGUI_INI if path is None else path
    if path not in _INI_BEFORE:
        if not _INI_BEFORE:
            atexit.register(lambda: [take_back_imgui_ini(p) for p in list(_INI_BEFORE)])
        _INI_BEFORE[path] = path.read_bytes() if path.is_file() else None
    return path


def take_back_imgui_ini(path: Path | None = None) -> None:
    """Remove the ini file ImGui wrote, or put back the one that was there before."""
    path = Path.cwd() / IMGUI_INI if path is None else path
    if path not in _INI_BEFORE:
        return
    before = _INI_BEFORE[path]
    try:
        if before is None:
            path.unlink(missing_ok=True)
        elif not path.is_file() or path.read_bytes() != before:
            path.write_bytes(before)  # someone else's layout file: left as found
    except OSError:
        pass  # the directory went away or turned read-only: nothing of ours to take back


def open_window(title: str, size: tuple[int, int], *, visible: bool = False,
                pos: tuple[int, int] = (100, 100)):
    """A ``ti.ui.Window`` of ``size`` = (width, height) pixels (Taichi must be initialised),
    its top-left corner at desktop pixel ``pos`` when ``visible`` (a window manager may move it).

    ``visible=False`` renders offscreen (read frames with ``get_image_buffer_as_numpy``; never
    call ``show()`` on it). Raises :class:`RenderUnavailable` with a one-line reason and fix when
    there is no display (for ``visible=True``), no Vulkan driver, or window creation fails.
    """
    import taichi as ti

    if visible and not has_display():
        raise RenderUnavailable("an on-screen window needs a display (DISPLAY or WAYLAND_DISPLAY "
                                "is not set); record a video instead with `taichi-sim record`")
    explicit = os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES")
    if platform.system() == "Linux" and not explicit and not _icd_files():
        raise RenderUnavailable(f"rendering needs Vulkan and no Vulkan driver is installed (no ICD "
                                f"file in {ICD_DIRS[0]}): {INSTALL_HINT}")
    watch_imgui_ini()  # destroying the window writes it: take_back_imgui_ini() after
    zero_ggui_vertex_staging()
    try:
        with _quiet_stderr():
            return ti.ui.Window(title, tuple(int(s) for s in size), vsync=visible, show_window=visible,
                                pos=tuple(int(p) for p in pos))
    except Exception as exc:  # RuntimeError from Taichi's RHI, or a wheel built without GGUI
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RenderUnavailable(f"rendering needs Vulkan and it is not usable here ({reason}): "
                                f"{INSTALL_HINT}") from None


def zero_ggui_vertex_staging() -> None:
    """Make GGUI's per-frame vertex staging arrays start zeroed (idempotent).

    GGUI 1.7.4 allocates each declared mesh's, particles' and lines' staging array
    uninitialised (``np.ndarray``) and fills only the attributes it was given: a mesh's texture
    coordinates keep whatever the memory held before, and a NaN there drops the whole mesh from
    the frame: a cloth drawn now and then without its surface (docs/design.md).
    """
    import taichi.ui  # noqa: F401  (loads the modules patched below)

    for name in ("taichi.ui.scene", "taichi.ui.canvas"):
        module = sys.modules.get(name)
        allocate = getattr(module, "get_vbo_field_v2", None)
        if allocate is None or getattr(allocate, "zero_filled", False):
            continue

        def zero_filled(vertices, _allocate=allocate):
            vbo = _allocate(vertices)
            vbo.fill(0.0)
            return vbo

        zero_filled.zero_filled = True
        module.get_vbo_field_v2 = zero_filled


def vulkan_problem() -> str | None:
    """None when an offscreen window opens here, else the one-line reason (for test skips).
    Taichi must be initialised and no other window open (the probe window is closed)."""
    try:
        window = open_window("taichi_sim probe", (8, 8))
    except RenderUnavailable as exc:
        return str(exc)
    window.destroy()
    take_back_imgui_ini()
    return None
