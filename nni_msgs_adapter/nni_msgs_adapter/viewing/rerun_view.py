"""Rerun views of single-machine-infinite-bus runs (pure core: numpy + rerun only).

Every run is identified by a free-form ``label`` (for example ``"b=0.3"``) that
becomes one entity path part, so that several runs overlay in the same views.
For a label ``L`` (escaped with :func:`rerun.escape_entity_path_part`) the entity
paths are:

=================================== ============================================
entity path                         content
=================================== ============================================
``/angle_deviation/L``              angle deviation ``d = delta - delta_bar`` (rad)
``/frequency_deviation/L``          frequency deviation ``d' / (2 pi)`` (Hz)
``/battery/L/power``                battery power ``P_ST`` (pu)
``/battery/L/limit_upper``          ``+b`` (pu), only for a finite ``b``
``/battery/L/limit_lower``          ``-b`` (pu), only for a finite ``b``
``/saturation/L``                   saturation flag, 1 while ``|w| >= b`` (-)
``/w_hat/L``                        closed-loop Lyapunov candidate ``W_hat`` (pu rad)
``/phase_portrait/L/trajectory``    ``(d, d')`` strip segments, rad and rad/s
``/phase_portrait/L/omega_boundary`` closed boundary of the invariant set Omega
``/parameters/L``                   static run parameters ``b`` (pu), ``f0_hz`` (Hz)
=================================== ============================================

``/phase_portrait`` itself (shared by all runs, static) holds a y-flip transform
(2D views draw y down; the flip makes ``d'`` point up) and the ``d``/``d'``
axes with ticks, sized by the last Omega boundary logged.

A network run (several generators of one case, :data:`NETWORK_VIEW`) is logged
generator by generator with the label ``gen<i>`` and the same paths, except
that the angle is the generator's angle relative to the centre of inertia,
``delta_i - delta_COI`` (rad), at ``/angle_coi/gen<i>``, and that there is no
W_hat and no phase portrait (no Omega is known for a network). Each generator
has its own colour (:func:`nni_msgs_adapter.viewing.palette.generator_colour_rgb`),
its name in the legend; battery powers and limits are in pu of its machine's rating.

All runs logged through :func:`open_recording` (the live bridge, ``nni-replay``)
share one application id and one recording id (``APP_ID``, ``RECORDING_ID``),
so that the viewer pools them into one recording: files of different runs
opened together (or merged with ``rerun rrd merge``) overlay in the same views.
Each run's colour depends on its battery limit only (:func:`nni_msgs_adapter.palette.colour_rgb`).

All time series live on one duration timeline (default ``"sim_time"``, seconds).
The phase-portrait trajectory is logged as consecutive strip segments, each
stamped with the time of its last sample; the phase-portrait view shows every
segment up to the time cursor, so scrubbing the timeline replays the
trajectory while the amount of data per update stays bounded.
"""

from __future__ import annotations

import math
import os
import shutil
import sys
import urllib.parse
from pathlib import Path
from typing import NamedTuple

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from nni_msgs_adapter.viewing.palette import colour_rgb

#: Default number of samples per phase-portrait strip segment (-).
PHASE_SEGMENT_SAMPLES = 50

#: Root of the phase portrait: y-flip, axes and ticks; runs are its children.
PHASE_PATH = "/phase_portrait"

#: Rerun application id of every stream this project writes.
APP_ID = "nni_battery_control"
#: Recording id of every stream this project writes: the viewer pools equal ids into one recording.
RECORDING_ID = "nni_battery_control_runs"

_LIMIT_ALPHA = 150
_OMEGA_COLOR = (200, 200, 200)
_AXES_COLOR = (120, 120, 120)
# 2D views draw y down; this transform makes d' point up.
_Y_UP = rr.Transform3D(scale=[1.0, -1.0, 1.0])
_LINE_WIDTH_PX = 1.5
_STRIP_RADIUS_PX = 1.0


class ViewKind(NamedTuple):
    """What a run's angle is and whether it has a phase portrait: a SMIB run or a generator of a network."""

    angle_root: str
    angle_name: str
    phase_portrait: bool


#: A single machine: the angle deviation d from the equilibrium, and the phase portrait with Omega.
SMIB_VIEW = ViewKind("/angle_deviation", "d (rad)", True)
#: A generator of a network: its angle relative to the centre of inertia; no phase portrait.
NETWORK_VIEW = ViewKind("/angle_coi", "δ-δ_COI (rad)", False)


class RunPaths(NamedTuple):
    """Entity paths of one labelled run (see the module docstring)."""

    angle: str
    frequency: str
    power: str
    limit_upper: str
    limit_lower: str
    saturation: str
    w_hat: str
    trajectory: str
    omega_boundary: str
    parameters: str


def run_paths(label: str, kind: ViewKind = SMIB_VIEW) -> RunPaths:
    """
    Return the entity paths used for the run ``label``.

    Parameters
    ----------
    label : str
        Free-form run label, e.g. ``"b=0.3"``; it is escaped into one path part.
    kind : ViewKind
        :data:`SMIB_VIEW` or :data:`NETWORK_VIEW` (where the angle goes).

    Returns
    -------
    RunPaths
        The entity paths of the run.
    """
    part = rr.escape_entity_path_part(label)
    return RunPaths(
        angle=f"{kind.angle_root}/{part}",
        frequency=f"/frequency_deviation/{part}",
        power=f"/battery/{part}/power",
        limit_upper=f"/battery/{part}/limit_upper",
        limit_lower=f"/battery/{part}/limit_lower",
        saturation=f"/saturation/{part}",
        w_hat=f"/w_hat/{part}",
        trajectory=f"{PHASE_PATH}/{part}/trajectory",
        omega_boundary=f"{PHASE_PATH}/{part}/omega_boundary",
        parameters=f"/parameters/{part}",
    )


def blueprint(
    timeline: str = "sim_time",
    phase_bounds: tuple[tuple[float, float], tuple[float, float]] | None = None,
    kind: ViewKind = SMIB_VIEW,
) -> rrb.Blueprint:
    """
    Build the viewer layout: five time-series views and the phase portrait (a network: four views).

    Parameters
    ----------
    timeline : str
        Duration timeline (seconds) shared by all views.
    phase_bounds : ((float, float), (float, float)) or None
        Minimum visible ``((d_min, d_max), (d'_min, d'_max))`` of the phase
        portrait in rad and rad/s; ``None`` lets the viewer fit the data.
    kind : ViewKind
        :data:`SMIB_VIEW` (angle deviation, W_hat, phase portrait) or
        :data:`NETWORK_VIEW` (angles relative to the centre of inertia, no W_hat or phase portrait).

    Returns
    -------
    rerun.blueprint.Blueprint
        The blueprint; send it with :meth:`rerun.RecordingStream.send_blueprint`.
    """
    legend = rrb.PlotLegend(corner=rrb.Corner2D.RightTop)
    # Simulated seconds from the runs' start (t = 0) on, the same range in every view: the views scroll
    # and zoom together, and runs of different lengths overlay from 0.
    axis_x = rrb.TimeAxis(link="LinkToGlobal", view_range=rr.encodings.TimeRange(
        start=rrb.TimeRangeBoundary.absolute(seconds=0.0), end=rrb.TimeRangeBoundary.infinite()))

    def series_view(origin: str, name: str, axis_y: rrb.ScalarAxis | None = None) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(origin=origin, name=name, plot_legend=legend, axis_x=axis_x, axis_y=axis_y,
                                  time_ranges=rrb.VisibleTimeRange(timeline, start=rrb.TimeRangeBoundary.infinite(),
                                                                   end=rrb.TimeRangeBoundary.infinite()))

    panels = rrb.TimePanel(timeline=timeline, play_state="Following", state="Collapsed"), \
        rrb.BlueprintPanel(state="Collapsed"), rrb.SelectionPanel(state="Collapsed")
    battery = rrb.Vertical(
        series_view("/battery", "Battery power P_ST and limits +-b (pu)"),
        series_view("/saturation", "Saturation (flag 0/1)", rrb.ScalarAxis(range=(-0.1, 1.1))),
        row_shares=[2, 1],
    )
    if not kind.phase_portrait:
        return rrb.Blueprint(
            rrb.Horizontal(
                rrb.Vertical(
                    series_view(kind.angle_root, "Angle relative to the centre of inertia, δ-δ_COI (rad)"),
                    series_view("/frequency_deviation", "Frequency deviation (Hz)"),
                ),
                battery,
            ),
            *panels,
        )
    bounds = None
    if phase_bounds is not None:
        (x_min, x_max), (y_min, y_max) = phase_bounds
        # The trajectory is drawn through a y-flip, so flip the bounds as well.
        bounds = rrb.VisualBounds2D(x_range=(x_min, x_max), y_range=(-y_max, -y_min))
    phase_view = rrb.Spatial2DView(
        origin="/",
        contents=f"{PHASE_PATH}/**",
        name="Phase portrait (d [rad] right, d' [rad/s] up)",
        visual_bounds=bounds,
        time_ranges=rrb.VisibleTimeRange(
            timeline,
            start=rrb.TimeRangeBoundary.infinite(),
            end=rrb.TimeRangeBoundary.cursor_relative(),
        ),
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                series_view(kind.angle_root, "Angle deviation (rad)"),
                series_view("/frequency_deviation", "Frequency deviation (Hz)"),
                series_view("/w_hat", "W_hat, closed-loop Lyapunov candidate (pu rad)"),
            ),
            battery,
            phase_view,
            column_shares=[1, 1, 0.8],
        ),
        *panels,
    )


def display_missing() -> bool:
    """True where a native viewer cannot open a window (Linux without X11 or Wayland)."""
    return sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _put_venv_rerun_on_path() -> None:
    """rr.spawn runs ``rerun`` from PATH; a venv entry point started by its full path has its bin dir off PATH."""
    if shutil.which("rerun") is None:
        os.environ["PATH"] = os.pathsep.join((str(Path(sys.executable).parent), os.environ.get("PATH", "")))


def recording_stream(app_id: str = APP_ID) -> rr.RecordingStream:
    """A recording stream with the project's shared recording id (runs in different files overlay)."""
    return rr.RecordingStream(app_id, recording_id=RECORDING_ID)


def open_recording(
    app_id: str,
    sink: tuple[str, str | int | None],
    *,
    layout: rrb.Blueprint | None = None,
) -> tuple[rr.RecordingStream, str | None]:
    """
    Create an explicit recording stream, attach a sink and send the blueprint.

    Parameters
    ----------
    app_id : str
        Rerun application id.
    sink : tuple
        ``("save", path)`` writes an ``.rrd`` file; ``("serve", port)`` hosts a
        gRPC server (``port``, or 9876 if ``None``) and the web viewer on
        port 9090, both on all network interfaces, for as long as the process
        runs; ``("connect", url)`` streams to a running viewer or server;
        ``("spawn", None)`` starts a native viewer.
    layout : rerun.blueprint.Blueprint or None
        Blueprint to send; defaults to :func:`blueprint`.

    Returns
    -------
    recording : rerun.RecordingStream
        The stream; independent of Rerun's global recording.
    url : str or None
        For ``"serve"``, the web-viewer URL that opens the live stream;
        otherwise ``None``.

    Raises
    ------
    ValueError
        If the sink kind is unknown.
    """
    kind, target = sink
    recording = recording_stream(app_id)
    url = None
    if kind == "save":
        recording.save(target)
    elif kind == "serve":
        grpc_url = recording.serve_grpc(grpc_port=target)
        rr.serve_web_viewer(open_browser=False)
        url = f"http://localhost:9090/?url={urllib.parse.quote(grpc_url, safe='')}"
    elif kind == "connect":
        recording.connect_grpc(target)
    elif kind == "spawn":
        _put_venv_rerun_on_path()
        recording.spawn()
    else:
        raise ValueError(f"unknown Rerun sink {kind!r}: expected 'save', 'serve', 'connect' or 'spawn'")
    recording.send_blueprint(blueprint() if layout is None else layout)
    return recording, url


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
        RGB colour of the run; ``None``: :func:`nni_msgs_adapter.palette.colour_rgb` of ``b``.
    segment_samples : int
        Samples per phase-portrait strip segment.
    kind : ViewKind
        :data:`SMIB_VIEW`, or :data:`NETWORK_VIEW` (``angle_dev_rad`` is then
        ``delta - delta_COI``; no phase portrait is drawn).

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
    if w_hat is not None:
        series.append(w_hat)
    series = [np.asarray(x, dtype=np.float64) for x in series]
    n = series[0].size
    if n == 0 or any(x.ndim != 1 or x.size != n for x in series):
        raise ValueError("sample arrays must be 1-D with one common non-zero length")
    t, d, d_dot, power, sat = series[:5]
    last = _segment_ends(n, segment_samples)
    paths = run_paths(label, kind)
    _log_run_statics(recording, label, paths, b, f0_hz, omega_boundary, color, kind)

    time = [rr.TimeColumn(timeline, duration=t)]
    values = {
        paths.angle: d,
        paths.frequency: d_dot / (2.0 * math.pi),
        paths.power: power,
        paths.saturation: sat,
    }
    if w_hat is not None:
        values[paths.w_hat] = series[5]
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


class LiveLogger:
    """
    Incremental logging of a running system, one sample at a time.

    Writes the same entity paths as :func:`log_trajectory`. The phase-portrait
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
        RGB colour of the run; ``None``: :func:`nni_msgs_adapter.palette.colour_rgb` of ``b``.
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
        if segment_samples < 1:
            raise ValueError("segment_samples must be >= 1")
        self.recording = recording
        self.paths = run_paths(label, kind)
        self.kind = kind
        self.b = float(b)
        self.timeline = timeline
        self.segment_samples = segment_samples
        self._pending: list[tuple[float, float]] = []
        _log_run_statics(recording, label, self.paths, b, f0_hz, omega_boundary, color, kind)

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
    if segment_samples < 1:
        raise ValueError("segment_samples must be >= 1")
    if n == 1:
        return np.array([0])
    return np.minimum(np.arange(segment_samples, n - 1 + segment_samples, segment_samples), n - 1)


def _log_run_statics(
    recording: rr.RecordingStream,
    label: str,
    paths: RunPaths,
    b: float,
    f0_hz: float,
    omega_boundary: np.ndarray | None,
    color: tuple[int, int, int] | None,
    kind: ViewKind,
) -> None:
    """Log the static styling, parameters and Omega boundary of a run, and the y-flip (a SMIB run's)."""
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
