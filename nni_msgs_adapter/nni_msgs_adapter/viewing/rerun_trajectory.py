"""Offline logging of a whole run into Rerun, column by column (pure core: numpy + rerun only).

The entity paths and the views are those of :mod:`rerun_layout`; ``nni-replay --rrd``
logs every generator of a recording with :func:`log_trajectory`.
"""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

from nni_msgs_adapter.viewing.rerun_layout import PHASE_SEGMENT_SAMPLES, SMIB_VIEW, RunPaths, ViewKind
from nni_msgs_adapter.viewing.rerun_statics import begin_run


def log_trajectory(
    recording: rr.RecordingStream,
    label: str,
    t_s: np.ndarray,
    angle_dev_rad: np.ndarray,
    speed_dev_rad_s: np.ndarray,
    battery_power_pu: np.ndarray,
    saturated: np.ndarray,
    w_hat: np.ndarray | None,
    b: float,
    f0_hz: float,
    omega_boundary: np.ndarray | None = None,
    timeline: str = "sim_time",
    *,
    color: tuple[int, int, int] | None = None,
    segment_samples: int = PHASE_SEGMENT_SAMPLES,
    kind: ViewKind = SMIB_VIEW,
    battery_charge_pu_s: np.ndarray | None = None,
) -> RunPaths:
    """
    Log a whole run column-wise (``send_columns``: fast for 1e4-1e5 samples).

    Parameters
    ----------
    recording : rerun.RecordingStream
        Target recording.
    label : str
        Run label, e.g. ``"b=0.3"``.
    t_s : numpy.ndarray
        Sample times (s), shape ``(n,)``.
    angle_dev_rad : numpy.ndarray
        Angle deviation ``d`` (rad), shape ``(n,)``.
    speed_dev_rad_s : numpy.ndarray
        Angle-deviation rate ``d'`` (rad/s), shape ``(n,)``.
    battery_power_pu : numpy.ndarray
        Battery power ``P_ST`` (pu), shape ``(n,)``.
    saturated : numpy.ndarray
        Saturation flags (bool or 0/1), shape ``(n,)``.
    w_hat : numpy.ndarray or None
        Closed-loop Lyapunov candidate ``W_hat`` (pu rad), shape ``(n,)``;
        ``None`` if not available.
    b : float
        Battery limit (pu); ``inf`` draws no limit lines, 0 is "no battery".
    f0_hz : float
        Nominal frequency (Hz), logged with the run parameters.
    omega_boundary : numpy.ndarray or None
        Boundary of the invariant set Omega as ``(m, 2)`` points ``(d, d')`` in
        rad and rad/s; it is drawn closed.
    timeline : str
        Duration timeline name.
    color : (int, int, int) or None
        RGB colour of the run; ``None``: :func:`nni_msgs_adapter.viewing.palette.colour_rgb` of ``b``.
    segment_samples : int
        Samples per phase-portrait strip segment.
    kind : ViewKind
        :data:`SMIB_VIEW`, or :data:`NETWORK_VIEW` (``angle_dev_rad`` is then
        ``delta - delta_COI``; no phase portrait is drawn).
    battery_charge_pu_s : numpy.ndarray or None
        A battery of finite energy's charge (pu s from empty), shape ``(n,)``; None: none drawn.

    Returns
    -------
    RunPaths
        The entity paths written.

    Raises
    ------
    ValueError
        If the sample arrays are not 1-D of one common non-zero length,
        ``segment_samples < 1``, ``b`` is negative or NaN, or
        ``omega_boundary`` is not of shape ``(m, 2)``.
    """
    series = [t_s, angle_dev_rad, speed_dev_rad_s, battery_power_pu, saturated]
    if battery_charge_pu_s is not None:
        series.append(battery_charge_pu_s)
    if w_hat is not None:
        series.append(w_hat)
    series = [np.asarray(x, dtype=np.float64) for x in series]
    n = series[0].size
    if n == 0 or any(x.ndim != 1 or x.size != n for x in series):
        raise ValueError("sample arrays must be 1-D with one common non-zero length")
    t, d, d_dot, power, sat = series[:5]
    paths = begin_run(recording, label, b, f0_hz, omega_boundary, color, kind, segment_samples,
                      charge=battery_charge_pu_s is not None)
    last = _segment_ends(n, segment_samples)

    time = [rr.TimeColumn(timeline, duration=t)]
    values = {
        paths.angle: d,
        paths.frequency: d_dot / (2.0 * math.pi),
        paths.power: power,
        paths.saturation: sat,
    }
    if w_hat is not None:
        values[paths.w_hat] = series[-1]
    if battery_charge_pu_s is not None:
        values[paths.charge] = series[5]
    for path, value in values.items():
        recording.send_columns(path, indexes=time, columns=rr.Scalars.columns(scalars=value))
    if math.isfinite(b):
        ends = [rr.TimeColumn(timeline, duration=t[[0, -1]])]
        for path, limit in ((paths.limit_upper, b), (paths.limit_lower, -b)):
            recording.send_columns(path, indexes=ends, columns=rr.Scalars.columns(scalars=[limit, limit]))
    if not kind.phase_portrait:
        return paths

    points = np.column_stack([d, d_dot])
    first = np.concatenate([[0], last[:-1]])
    recording.send_columns(
        paths.trajectory,
        indexes=[rr.TimeColumn(timeline, duration=t[last])],
        columns=rr.LineStrips2D.columns(strips=[points[i : j + 1] for i, j in zip(first, last)]),
    )
    return paths


def _segment_ends(n: int, segment_samples: int) -> np.ndarray:
    """
    Return the last sample index of each phase-portrait strip segment.

    Segment ``k`` spans samples ``ends[k-1] .. ends[k]`` (``ends[-1]`` read as
    0), so consecutive segments share an end point and the strip has no gaps.

    Parameters
    ----------
    n : int
        Number of samples (-), at least 1.
    segment_samples : int
        Samples per segment (-), at least 1.

    Returns
    -------
    numpy.ndarray
        Increasing sample indices ending with ``n - 1``.
    """
    if n == 1:
        return np.array([0])
    return np.minimum(np.arange(segment_samples, n - 1 + segment_samples, segment_samples), n - 1)
