"""What every run logs once, static: line styles and legend names, parameters, Omega and the phase axes (pure core).

Every run starts with :func:`begin_run`, the offline log of a whole run
(:mod:`rerun_trajectory`) and the live logger (:mod:`rerun_live`) alike, so that both
check a run and draw it the same way. Each run's colour
depends on its battery limit only (:func:`nni_msgs_adapter.viewing.palette.colour_rgb`),
unless the caller gives one (a network's generators).
"""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

from nni_msgs_adapter.viewing.palette import colour_rgb
from nni_msgs_adapter.viewing.rerun_layout import PHASE_PATH, RunPaths, ViewKind, run_paths

_LIMIT_ALPHA = 150
_OMEGA_COLOR = (200, 200, 200)
_AXES_COLOR = (120, 120, 120)
# 2D views draw y down; this transform makes d' point up.
_Y_UP = rr.Transform3D(scale=[1.0, -1.0, 1.0])
_LINE_WIDTH_PX = 1.5
_STRIP_RADIUS_PX = 1.0


def begin_run(
    recording: rr.RecordingStream,
    label: str,
    b: float,
    f0_hz: float,
    omega_boundary: np.ndarray | None,
    color: tuple[int, int, int] | None,
    kind: ViewKind,
    segment_samples: int,
    charge: bool = False,
) -> RunPaths:
    """The start of a run, whole or live: its description checked, its statics logged, its entity paths.

    The statics are the run's line styles and legend names, its parameters, the Omega
    boundary (closed) with the phase axes over it, and the y-flip (a SMIB run's); with ``charge``
    the style of the battery's charge.

    Raises
    ------
    ValueError
        If ``segment_samples < 1``, ``b`` is negative or NaN, or ``omega_boundary`` is not
        of shape ``(m, 2)`` (or given for a network run).
    """
    if segment_samples < 1:
        raise ValueError("segment_samples must be >= 1")
    paths = run_paths(label, kind)
    if not b >= 0.0:
        raise ValueError(f"battery limit b must be >= 0 (pu), got {b}")
    if not kind.phase_portrait and omega_boundary is not None:
        raise ValueError("omega_boundary: a network run has no phase portrait to draw it in")
    boundary = None
    if omega_boundary is not None:
        boundary = np.asarray(omega_boundary, dtype=np.float64)
        if boundary.ndim != 2 or boundary.shape[0] < 2 or boundary.shape[1] != 2:
            raise ValueError("omega_boundary must have shape (m, 2) with m >= 2")
        if not np.array_equal(boundary[0], boundary[-1]):
            boundary = np.vstack([boundary, boundary[:1]])
    if color is None:
        color = colour_rgb(b)
    radius = rr.components.Radius.ui_points(_STRIP_RADIUS_PX)

    def line(name: str, *, step: bool = False, rgb=color, width: float = _LINE_WIDTH_PX) -> rr.SeriesLines:
        # Step-like signals (held between samples) are drawn as steps and never averaged
        # over a pixel: a 0/1 flag must not show 0.5, a held power its true values.
        if step:
            return rr.SeriesLines(colors=rgb, widths=width, names=f"{name} {label}", interpolation_mode="StepAfter",
                                  aggregation_policy="Off")
        return rr.SeriesLines(colors=rgb, widths=width, names=f"{name} {label}")

    styles = {
        paths.angle: line(kind.angle_name),
        paths.frequency: line("Δf (Hz)"),
        paths.power: line("P_ST (pu)", step=True),
        paths.saturation: line("saturated (0/1)", step=True),
        paths.parameters: rr.AnyValues(b=b, f0_hz=f0_hz),
    }
    if charge:
        styles[paths.charge] = line("charge (pu s)")
    if kind.phase_portrait:
        styles[paths.w_hat] = line("W_hat (pu rad)")
        # Static colour and width apply to every (time-stamped) trajectory segment.
        styles[paths.trajectory] = rr.LineStrips2D.from_fields(colors=color, radii=radius)
        styles[PHASE_PATH] = _Y_UP
    if math.isfinite(b):
        limit_color = (*color, _LIMIT_ALPHA)
        styles[paths.limit_upper] = line("+b (pu)", step=True, rgb=limit_color, width=1.0)
        styles[paths.limit_lower] = line("-b (pu)", step=True, rgb=limit_color, width=1.0)
    if boundary is not None:
        styles[paths.omega_boundary] = rr.LineStrips2D([boundary], colors=_OMEGA_COLOR, radii=radius,
                                                       labels=f"Omega {label}", show_labels=True)
    for path, archetype in styles.items():
        recording.log(path, archetype, static=True)
    if boundary is not None:
        _log_phase_axes(recording, boundary)
    return paths


def _log_phase_axes(recording: rr.RecordingStream, boundary: np.ndarray) -> None:
    """
    Draw the phase-portrait axes with ticks over the extent of ``boundary``.

    Ticks are spaced by the power of ten just below each axis' extent (at most
    ten per axis). Axes and ticks are static components of :data:`PHASE_PATH`;
    the last boundary logged sets their extent.

    Parameters
    ----------
    recording : rerun.RecordingStream
        Target recording.
    boundary : numpy.ndarray
        Points ``(d, d')`` in rad and rad/s, shape ``(m, 2)``.
    """
    lo, hi = np.minimum(boundary.min(axis=0), 0.0), np.maximum(boundary.max(axis=0), 0.0)
    margin = 0.1 * (hi - lo)
    # The axes overshoot the boundary by a margin, where the unit labels sit clear of the ticks.
    ends_lo, ends_hi = lo - margin, hi + margin
    axes = [[[ends_lo[0], 0.0], [ends_hi[0], 0.0]], [[0.0, ends_lo[1]], [0.0, ends_hi[1]]]]
    ticks, labels = [[ends_hi[0], 0.0], [0.0, ends_hi[1]]], ["d (rad)", "d' (rad/s)"]
    for axis, span in enumerate(hi - lo):
        if span == 0.0:
            continue
        step = 10.0 ** np.floor(np.log10(span))
        for k in step * np.arange(np.ceil(lo[axis] / step), np.floor(hi[axis] / step) + 1.0):
            if k != 0.0:
                ticks.append([k, 0.0] if axis == 0 else [0.0, k])
                labels.append(f"{k:g}")
    recording.log(
        PHASE_PATH,
        rr.LineStrips2D(axes, colors=_AXES_COLOR, radii=rr.components.Radius.ui_points(0.5)),
        rr.Points2D(
            ticks, colors=_AXES_COLOR, radii=rr.components.Radius.ui_points(2.0), labels=labels, show_labels=True
        ),
        static=True,
    )
