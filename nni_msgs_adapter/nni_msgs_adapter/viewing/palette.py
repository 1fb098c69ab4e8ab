"""One colour per battery limit b, the same in every figure and in the Rerun view.

A pure function of b (no registry, no state): the paper's limits get fixed,
well separated colours; any other b a hue stepped by the golden ratio along
log b, so that limits a few tens of percent apart look different. Pure python:
no matplotlib, rerun or ROS import.
"""

from __future__ import annotations

import colorsys
import math

#: The paper's limits: no battery grey, then matplotlib's first three tab10 colours.
_PAPER_COLOURS = {0.0: "#7f7f7f", 0.2: "#1f77b4", 0.3: "#ff7f0e", math.inf: "#2ca02c"}
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def colour_hex(b: float) -> str:
    """``'#rrggbb'`` of battery limit ``b`` (pu, >= 0 or inf)."""
    if b in _PAPER_COLOURS:
        return _PAPER_COLOURS[b]
    if not b > 0:
        raise ValueError(f"battery limit must be >= 0 or inf, got {b}")
    hue = (_GOLDEN * math.log(b) / math.log(1.25)) % 1.0
    red, green, blue = colorsys.hsv_to_rgb(hue, 0.75, 0.8)
    return "#" + "".join(f"{round(255 * c):02x}" for c in (red, green, blue))


def colour_rgb(b: float) -> tuple[int, int, int]:
    """``(r, g, b)`` 0..255 of battery limit ``b``, e.g. for a Rerun colour."""
    text = colour_hex(b)
    return tuple(int(text[i:i + 2], 16) for i in (1, 3, 5))
