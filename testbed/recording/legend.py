"""The viewer's colour key: an image drawn from testbed/recording/palette.py, logged once as static ``legend``
and shown in the blueprint's legend panel.

    legend_image() -> (H, W, 3) uint8     the key on the viewer's dark background
    legend_png() -> bytes                 the same, PNG-encoded (what the recording logs: ~15 kB, not ~400)
    ENTRIES                               (label, swatch kind, colour) in drawing order

Swatch kinds: "dot" (points), "solid" (a filled box), "fill" (a translucent filled box), "box" (a wireframe),
"ring" (an ellipse outline), "line", "arrow"; several colours in one swatch stand for colours per vehicle id (rerun's) or per track
(its diagnostics slot's, testbed/recording/slots.py).
"""
from __future__ import annotations

import functools

import numpy as np

from . import palette as pal

_IDS = ((230, 159, 0), (86, 180, 233), (0, 158, 115), (204, 121, 167))  # a few colours standing for "per id"
_SLOTS = tuple(tuple(int(v) for v in c) for c in pal.SLOTS[:3])  # tracks: their slot's colour

ENTRIES: tuple[tuple[str, str, tuple], ...] = (
    ("sensor car", "solid", pal.EGO),
    ("true vehicle (colour: its id)", "box", _IDS),
    ("ground point", "dot", pal.GROUND),
    ("object point (colour: detection)", "dot", tuple(map(tuple, pal.CLUSTERS[:4]))),
    ("detection", "dot", pal.DETECTION),
    ("clutter detection", "dot", pal.CLUTTER),
    ("box: merged / split / completed", "box", (pal.MERGED, pal.SPLIT, pal.COMPLETED)),
    ("rejected object", "dot", pal.REJECTED),
    ("track (colour: as in the plots) / tentative", "dot", (*_SLOTS, pal.UNSLOTTED)),
    ("track velocity (0.5 s)", "arrow", _SLOTS[:1]),
    ("2-sigma ellipse and gate", "ring", _SLOTS[:2]),
    ("track trail (a dot per 0.5 s, last 5 s)", "dot", _SLOTS[1:3]),
    ("SVSF layer (true size, >= 0.6 m, above car)", "fill", pal.LAYER),
    ("occlusion shadow (full level)", "line", pal.SHADOW),
    ("ground error (full level)", "dot", (pal.OBJECT_AS_ROAD, pal.ROAD_AS_OBJECT)),
)
EXTRAS: dict[str, tuple[str, tuple[str, str, tuple]]] = {
    "sensors": ("rejected object", ("further sensor's detection (radar), above", "dot", pal.SENSOR)),
    "boxes": ("2-sigma ellipse and gate", ("track box (tracker.box)", "box", _SLOTS[:2])),
}
"""Rows a run adds when it draws them: name -> (the row they follow, the row): a further sensor's detections,
box tracking's track boxes."""
BACKGROUND = (24, 24, 28)
ROW_PX, WIDTH_PX, SWATCH_PX = 25, 330, 54


def _colours(c) -> list[tuple]:
    return [tuple(c)] if isinstance(c[0], (int, np.integer)) else [tuple(x) for x in c]


def entries(extras: tuple[str, ...] = ()) -> tuple[tuple[str, str, tuple], ...]:
    """:data:`ENTRIES` with the :data:`EXTRAS` rows named in ``extras``, each after the row it follows."""
    out = list(ENTRIES)
    for name in extras:
        after, row = EXTRAS[name]
        out.insert([e[0] for e in out].index(after) + 1, row)
    return tuple(out)


@functools.lru_cache(maxsize=4)
def legend_image(extras: tuple[str, ...] = ()) -> np.ndarray:
    """The colour key (H, W, 3) uint8: one row per :data:`ENTRIES` entry, a swatch in the entry's style
    and colour(s) on the left, the label on the right; translucent colours blended on the background."""
    from PIL import Image, ImageDraw, ImageFont

    rows = entries(extras)
    h = ROW_PX * (len(rows) + 1)
    img = Image.new("RGB", (WIDTH_PX, h), BACKGROUND)
    d = ImageDraw.Draw(img)
    font = ImageFont.load_default(size=15)
    d.text((8, 4), "legend", fill=(235, 235, 235), font=font)
    for row, (label, kind, colour) in enumerate(rows, start=1):
        y0 = row * ROW_PX
        cols = [_blend(c) for c in _colours(colour)]
        _swatch(d, kind, cols, 8, y0 + 4, SWATCH_PX, ROW_PX - 8)
        d.text((8 + SWATCH_PX + 10, y0 + 4), label, fill=(225, 225, 225), font=font)
    return np.asarray(img, dtype=np.uint8)


@functools.lru_cache(maxsize=4)
def legend_png(extras: tuple[str, ...] = ()) -> bytes:
    """:func:`legend_image` as PNG bytes."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(legend_image(extras)).save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def _blend(c: tuple) -> tuple[int, int, int]:
    """An RGB(A) colour as drawn on the background (alpha blended, as the viewer draws translucent ones)."""
    if len(c) == 3:
        return tuple(int(v) for v in c)
    a = c[3] / 255.0
    return tuple(int(round(a * v + (1 - a) * b)) for v, b in zip(c[:3], BACKGROUND))


def _swatch(d, kind: str, cols: list, x: int, y: int, w: int, h: int) -> None:
    n = len(cols)
    step = w / n
    for i, c in enumerate(cols):
        a, b = int(x + i * step), int(x + (i + 1) * step) - 3
        if kind == "dot":
            r = min(h, b - a) // 2
            cx, cy = (a + b) // 2, y + h // 2
            d.ellipse((cx - r + 2, cy - r + 2, cx + r - 2, cy + r - 2), fill=c)
        elif kind == "solid" or kind == "fill":
            d.rectangle((a, y + 2, b, y + h - 2), fill=c)
        elif kind == "box":
            d.rectangle((a, y + 2, b, y + h - 2), outline=c, width=2)
        elif kind == "ring":
            d.ellipse((a, y + 1, b, y + h - 1), outline=c, width=2)
        elif kind == "line":
            d.line((a, y + h - 3, b, y + 3), fill=c, width=3)
        elif kind == "arrow":
            d.line((a, y + h // 2, b - 6, y + h // 2), fill=c, width=3)
            d.polygon(((b, y + h // 2), (b - 9, y + 2), (b - 9, y + h - 2)), fill=c)
        else:
            raise ValueError(f"unknown swatch kind {kind!r}")
