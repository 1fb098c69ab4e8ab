"""One colour per battery limit b, the same in every figure and in the Rerun view; one per generator of a network.

A pure function of b (no registry, no state): the paper's limits get fixed,
well separated colours; any other b a hue stepped by the golden ratio along
log b, so that limits a few tens of percent apart look different. The
generators of a network (whose batteries often share one b) are told apart by
their index instead: matplotlib's tab10 colours, then hues stepped by the
golden ratio. Pure python: no matplotlib, rerun or ROS import.
"""

from __future__ import annotations

import colorsys
import math

#: The paper's limits: no battery grey, then matplotlib's first three tab10 colours.
_PAPER_COLOURS = {0.0: "#7f7f7f", 0.2: "#1f77b4", 0.3: "#ff7f0e", math.inf: "#2ca02c"}
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
#: matplotlib's tab10 colours, the first ten generators'.
_TAB10 = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
          "#17becf")


def colour_hex(b: float) -> str:
    """``'#rrggbb'`` of battery limit ``b`` (pu, >= 0 or inf)."""
    if b in _PAPER_COLOURS:
        return _PAPER_COLOURS[b]
    if not b > 0:
        raise ValueError(f"battery limit must be >= 0 or inf, got {b}")
    return _hue_hex(_GOLDEN * math.log(b) / math.log(1.25))


def colour_rgb(b: float) -> tuple[int, int, int]:
    """``(r, g, b)`` 0..255 of battery limit ``b``, e.g. for a Rerun colour."""
    return _rgb(colour_hex(b))


def generator_colour_rgb(index: int) -> tuple[int, int, int]:
    """``(r, g, b)`` 0..255 of generator ``index`` (0-based, case order) of a network."""
    if index < 0:
        raise ValueError(f"generator index must be >= 0, got {index}")
    return _rgb(_TAB10[index] if index < len(_TAB10) else _hue_hex(_GOLDEN * index))


def _hue_hex(turns: float) -> str:
    """``'#rrggbb'`` of the hue ``turns`` (mod 1) at the palette's saturation and value."""
    red, green, blue = colorsys.hsv_to_rgb(turns % 1.0, 0.75, 0.8)
    return "#" + "".join(f"{round(255 * c):02x}" for c in (red, green, blue))


def _rgb(text: str) -> tuple[int, int, int]:
    return tuple(int(text[i:i + 2], 16) for i in (1, 3, 5))
