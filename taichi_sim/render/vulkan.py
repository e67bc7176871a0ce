"""Opening a GGUI window, or saying in one line why none can be opened.

GGUI renders with Vulkan. On a headless Linux machine Mesa's software driver (Debian package
``mesa-vulkan-drivers``) is enough for offscreen rendering; an on-screen window also needs a
display (``DISPLAY`` or ``WAYLAND_DISPLAY``).

Keep one window open at a time: in Taichi 1.7.4, closing (or garbage-collecting) a GGUI window
breaks every other window still open, and a window must be closed before ``ti.init`` runs again.
"""
from __future__ import annotations

import contextlib
import glob
import os
import platform

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


def open_window(title: str, size: tuple[int, int], *, visible: bool = False):
    """A ``ti.ui.Window`` of ``size`` = (width, height) pixels (Taichi must be initialised).

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
    try:
        with _quiet_stderr():
            return ti.ui.Window(title, tuple(int(s) for s in size), vsync=visible, show_window=visible)
    except Exception as exc:  # RuntimeError from Taichi's RHI, or a wheel built without GGUI
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RenderUnavailable(f"rendering needs Vulkan and it is not usable here ({reason}): "
                                f"{INSTALL_HINT}") from None


def vulkan_problem() -> str | None:
    """None when an offscreen window opens here, else the one-line reason (for test skips).
    Taichi must be initialised and no other window open (the probe window is closed)."""
    try:
        window = open_window("taichi_sim probe", (8, 8))
    except RenderUnavailable as exc:
        return str(exc)
    window.destroy()
    return None
