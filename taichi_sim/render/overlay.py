"""Text burnt into recorded frames (labels over side-by-side panels, a caption, warnings).

GGUI's 3D canvas has no text; recordings get theirs from Pillow's built-in font.
"""
from __future__ import annotations

import math
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


def word_layout(text: str, size: int, f=None) -> tuple[list[tuple[str, float]], float]:
    """Each word of ``text`` with its x offset (px) from the text's left edge, and the text's
    width (px), for the font of ``size`` pixels. A space is at least 0.4 of the size (whole pixels): Pillow's
    default font hints its space to 2 px at 11 px (frames 330 px tall, as the GIFs are), which
    next to a letter's side bearings read as no space at all ("diverged att=0.248s")."""
    f = f or font(size)
    space = max(f.getlength(" "), math.ceil(0.4 * size))
    words, x = [], 0.0
    for k, word in enumerate(text.split(" ")):
        if k:
            x += space
        words.append((word, x))
        x += f.getlength(word)
    return words, x


def burn(image: np.ndarray, labels: list[Label]) -> np.ndarray:
    """A copy of ``image`` ((H, W, 3) uint8) with ``labels`` drawn on dark boxes."""
    canvas = Image.fromarray(image)
    draw = ImageDraw.Draw(canvas)
    size = font_size(image.shape[0])
    f = font(size)
    pad = max(2, size // 4)
    for label in labels:
        if not label.text:
            continue
        words, width = word_layout(label.text, size, f)
        left = label.x - {"l": 0.0, "m": width / 2, "r": width}[label.anchor[0]]
        _, top, _, bottom = draw.textbbox((label.x, label.y), label.text, font=f, anchor=label.anchor)
        # each word from its left edge on the whole line's baseline ("t" and "b" are each word's own)
        baseline = label.y + top - draw.textbbox((label.x, label.y), label.text, font=f, anchor="ls")[1]
        draw.rectangle((left - pad, top - pad, left + width + pad, bottom + pad), fill=BOX)
        for word, dx in words:
            if word:
                draw.text((left + dx, baseline), word, font=f, fill=label.color, anchor="ls")
    return np.asarray(canvas)
