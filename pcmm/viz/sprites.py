"""Pictures (PNG, transparent) of the engineer's symbols of :mod:`pcmm.viz.sketch`, for the replay
page, which lays each on a flat plate riding on its link.  A sprite covers the square
``[-HALF s, HALF s]^2`` of its symbol's frame (``s`` the symbols' size), its centre on the symbol's
point; the shapes are those of the 2D sketch (:mod:`pcmm.viz.draw2d`)."""
from __future__ import annotations

import functools
import io
import math

HALF = 2.0  # the sprite spans [-HALF s, HALF s] in x and y
N = 256  # pixels a side
INK = (0, 0, 0, 255)
WHITE = (255, 255, 255, 255)
CUT = (123, 63, 181, 255)
STOP = (68, 68, 68, 255)
RED = (192, 0, 0, 255)


def _px(x: float, y: float) -> tuple[float, float]:
    """Symbol frame (units of s) -> sprite pixel."""
    return ((x + HALF) / (2 * HALF) * N, (HALF - y) / (2 * HALF) * N)


def _circle(draw, x, y, r, **kw):
    (u0, v0), (u1, v1) = _px(x - r, y + r), _px(x + r, y - r)
    draw.ellipse([u0, v0, u1, v1], **kw)


@functools.cache  # a few kinds and shapes; a page draws each many times
def sprite(kind: str, shape: str = "") -> bytes:
    """The PNG of one symbol kind (``ground``, ``pivot``, ``revolute``, ``locked``, ``slider``,
    ``cut``, ``stop``, ``arc``)."""
    from PIL import Image, ImageDraw
    img = Image.new("RGBA", (N, N), (0, 0, 0, 0))
    d = ImageDraw.Draw(img)
    w = max(2, N // 64)
    if kind == "ground":
        d.line([_px(-1.2, -1.2), _px(1.2, -1.2)], fill=INK, width=w)
        for k in range(7):
            x = -1.2 + k * 0.4
            d.line([_px(x, -1.2), _px(x - 0.4, -1.6)], fill=INK, width=max(1, w - 1))
    elif kind == "pivot":
        d.polygon([_px(0, 0), _px(-0.7, -1.2), _px(0.7, -1.2)], fill=WHITE, outline=INK, width=w)
        _circle(d, 0, 0, 0.35, fill=WHITE, outline=INK, width=w)
    elif kind == "revolute":
        _circle(d, 0, 0, 0.35, fill=WHITE, outline=INK, width=w)
    elif kind == "locked":
        if shape == "square":
            d.rectangle([*_px(-0.5, 0.5), *_px(0.5, -0.5)], fill=INK)
        else:
            _circle(d, 0, 0, 0.45, fill=INK)
    elif kind == "slider":
        d.rectangle([*_px(-0.8, 0.45), *_px(0.8, -0.45)], fill=WHITE, outline=INK, width=w)
    elif kind == "cut":
        _circle(d, 0, 0, 0.4, fill=WHITE, outline=CUT, width=w)
        d.line([_px(-0.6, -0.6), _px(0.6, 0.6)], fill=CUT, width=w)
    elif kind == "stop":
        if shape == "joint":
            d.line([_px(0.5, 0), _px(1.6, 0)], fill=STOP, width=3 * w)
        else:
            d.rectangle([*_px(-0.5, 0.8), *_px(0.0, -0.8)], fill=STOP, outline=INK)
            for k in range(5):
                y = -0.8 + k * 0.4
                d.line([_px(-0.5, y), _px(0.0, y + 0.4)], fill=WHITE, width=1)
    elif kind == "arc":
        r = 1.3
        (u0, v0), (u1, v1) = _px(-r, r), _px(r, -r)
        # PIL's angles run clockwise from +x (y down): the arc from 30 deg to 300 deg counter-clockwise
        d.arc([u0, v0, u1, v1], start=360 - 300, end=360 - 30, fill=RED, width=2 * w)
        sense = -1 if shape == "-" else 1
        end = math.radians(300 if sense > 0 else 30)
        ex, ey = r * math.cos(end), r * math.sin(end)
        tx, ty = -math.sin(end) * sense, math.cos(end) * sense
        nx, ny = -ty, tx
        tip = (ex + 0.45 * tx, ey + 0.45 * ty)
        d.polygon([_px(*tip), _px(ex - 0.3 * nx, ey - 0.3 * ny), _px(ex + 0.3 * nx, ey + 0.3 * ny)], fill=RED)
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue()
