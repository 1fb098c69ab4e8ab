"""Live logging into Rerun, one sample at a time, as the bridge receives them (pure core: numpy + rerun only).

The entity paths and the views are those of :mod:`rerun_layout`, the same as
:func:`rerun_trajectory.log_trajectory` writes for a whole run.
"""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

from nni_msgs_adapter.viewing.rerun_layout import PHASE_SEGMENT_SAMPLES, SMIB_VIEW, ViewKind
from nni_msgs_adapter.viewing.rerun_statics import begin_run


class LiveLogger:
    """
    Incremental logging of a running system, one sample at a time.

    Writes the same entity paths as :func:`rerun_trajectory.log_trajectory`. The phase-portrait
    strip is extended every ``segment_samples`` samples with only the new
    points, so the cost per sample is bounded.

    Parameters
    ----------
    recording : rerun.RecordingStream
        Target recording.
    label : str
        Run label, e.g. ``"b=0.3"``.
    b : float
        Battery limit (pu); ``inf`` draws no limit lines.
    f0_hz : float
        Nominal frequency (Hz), logged with the run parameters.
    omega_boundary : numpy.ndarray or None
        Boundary of Omega as ``(m, 2)`` points in rad and rad/s.
    timeline : str
        Duration timeline name.
    color : (int, int, int) or None
        RGB colour of the run; ``None``: :func:`nni_msgs_adapter.viewing.palette.colour_rgb` of ``b``.
    segment_samples : int
        Samples per phase-portrait strip segment.

    Raises
    ------
    ValueError
        If ``segment_samples < 1``, ``b`` is negative or NaN, or
        ``omega_boundary`` is not of shape ``(m, 2)``.
    """

    def __init__(
        self,
        recording: rr.RecordingStream,
        label: str,
        b: float,
        f0_hz: float,
        omega_boundary: np.ndarray | None = None,
        timeline: str = "sim_time",
        *,
        color: tuple[int, int, int] | None = None,
        segment_samples: int = PHASE_SEGMENT_SAMPLES,
        kind: ViewKind = SMIB_VIEW,
    ) -> None:
        self.recording = recording
        self.paths = begin_run(recording, label, b, f0_hz, omega_boundary, color, kind, segment_samples)
        self.kind = kind
        self.b = float(b)
        self.timeline = timeline
        self.segment_samples = segment_samples
        self._pending: list[tuple[float, float]] = []

    def log(
        self,
        t_s: float,
        angle_dev_rad: float,
        speed_dev_rad_s: float,
        battery_power_pu: float,
        saturated: bool,
        w_hat: float | None = None,
    ) -> None:
        """
        Log one sample.

        Parameters
        ----------
        t_s : float
            Sample time (s).
        angle_dev_rad : float
            Angle deviation ``d`` (rad).
        speed_dev_rad_s : float
            Angle-deviation rate ``d'`` (rad/s).
        battery_power_pu : float
            Battery power ``P_ST`` (pu).
        saturated : bool
            Whether the battery is saturated.
        w_hat : float or None
            Closed-loop Lyapunov candidate ``W_hat`` (pu rad), if available.
        """
        rec, paths = self.recording, self.paths
        rec.set_time(self.timeline, duration=t_s)
        rec.log(paths.angle, rr.Scalars(angle_dev_rad))
        rec.log(paths.frequency, rr.Scalars(speed_dev_rad_s / (2.0 * math.pi)))
        rec.log(paths.power, rr.Scalars(battery_power_pu))
        rec.log(paths.saturation, rr.Scalars(float(saturated)))
        if w_hat is not None:
            rec.log(paths.w_hat, rr.Scalars(w_hat))
        if math.isfinite(self.b):
            rec.log(paths.limit_upper, rr.Scalars(self.b))
            rec.log(paths.limit_lower, rr.Scalars(-self.b))
        if not self.kind.phase_portrait:
            return
        self._pending.append((angle_dev_rad, speed_dev_rad_s))
        if len(self._pending) > self.segment_samples:
            self.flush()

    def flush(self) -> None:
        """Log the phase-portrait points not yet drawn, at the current time."""
        if len(self._pending) > 1:
            self.recording.log(self.paths.trajectory, rr.LineStrips2D([self._pending]))
            self._pending = self._pending[-1:]
