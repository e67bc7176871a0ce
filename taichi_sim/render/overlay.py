"""Text burnt into recorded frames (labels over side-by-side panels, a caption, warnings).

GGUI's 3D canvas has no text; recordings get theirs from Pillow's built-in font.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

TEXT = (235, 237, 240)
WARNING = (255, 110, 96)
BOX = (12, 14, 18)


@dataclass(frozen=True)
class Label:
    """A line of text at pixel ``(x, y)`` (from the top-left corner).

    ``anchor`` is Pillow's: "mb" centres the text's bottom on the point, "lb" starts it there.
    """

    text: str
    x: float
    y: float
    color: tuple[int, int, int] = TEXT
    anchor: str = "mb"


@lru_cache(maxsize=8)
def font(size: int):
    """Pillow's default font at ``size`` pixels (a scalable one where FreeType is available)."""
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: a fixed bitmap font
        return ImageFont.load_default()


def font_size(height: int) -> int:
    """Text height (px) for frames ``height`` pixels tall."""
    return max(11, round(height / 30))


def burn(image: np.ndarray, labels: list[Label]) -> np.ndarray:
    """A copy of ``image`` ((H, W, 3) uint8) with ``labels`` drawn on dark boxes."""
    canvas = Image.fromarray(image)
    draw = ImageDraw.Draw(canvas)
    f = font(font_size(image.shape[0]))
    pad = max(2, font_size(image.shape[0]) // 4)
    for label in labels:
        if not label.text:
            continue
        box = draw.textbbox((label.x, label.y), label.text, font=f, anchor=label.anchor)
        draw.rectangle((box[0] - pad, box[1] - pad, box[2] + pad, box[3] + pad), fill=BOX)
        draw.text((label.x, label.y), label.text, font=f, fill=label.color, anchor=label.anchor)
    return np.asarray(canvas)
