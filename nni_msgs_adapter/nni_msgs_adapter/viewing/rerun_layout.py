"""Where a run's signals go in Rerun and how the viewer lays them out (pure core: rerun only).

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

All time series live on one duration timeline (default ``"sim_time"``, seconds).
The phase-portrait trajectory is logged as consecutive strip segments, each
stamped with the time of its last sample; the phase-portrait view shows every
segment up to the time cursor, so scrubbing the timeline replays the
trajectory while the amount of data per update stays bounded.
"""

from __future__ import annotations

from typing import NamedTuple

import rerun as rr
import rerun.blueprint as rrb

#: Default number of samples per phase-portrait strip segment (-).
PHASE_SEGMENT_SAMPLES = 50

#: Root of the phase portrait: y-flip, axes and ticks; runs are its children.
PHASE_PATH = "/phase_portrait"


class ViewKind(NamedTuple):
    """What a run's angle is and whether it has a phase portrait: a SMIB run or a generator of a network."""

    angle_root: str
    angle_name: str
    phase_portrait: bool


#: A single machine: the angle deviation d from the equilibrium, and the phase portrait with Omega.
SMIB_VIEW = ViewKind("/angle_deviation", "d (rad)", True)
#: A generator of a network: its angle relative to the centre of inertia; no phase portrait.
NETWORK_VIEW = ViewKind("/angle_coi", "δ-δ_COI (rad)", False)


#: Where a run's battery charge goes (a battery of finite energy), and the name of its view.
CHARGE_ROOT = "/battery_charge"
CHARGE_VIEW_NAME = "Battery charge (pu s from empty; full at twice its energy)"


class RunPaths(NamedTuple):
    """Entity paths of one labelled run (see the module docstring)."""

    angle: str
    frequency: str
    power: str
    limit_upper: str
    limit_lower: str
    saturation: str
    w_hat: str
    charge: str
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
        charge=f"{CHARGE_ROOT}/{part}",
        trajectory=f"{PHASE_PATH}/{part}/trajectory",
        omega_boundary=f"{PHASE_PATH}/{part}/omega_boundary",
        parameters=f"/parameters/{part}",
    )


def blueprint(
    timeline: str = "sim_time",
    phase_bounds: tuple[tuple[float, float], tuple[float, float]] | None = None,
    kind: ViewKind = SMIB_VIEW,
    battery_charge: bool = False,
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
    battery_charge : bool
        Whether a view of the batteries' charge is added (runs with a battery of finite energy).

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
    battery_views = [series_view("/battery", "Battery power P_ST and limits +-b (pu)"),
                     series_view("/saturation", "Saturation (flag 0/1)", rrb.ScalarAxis(range=(-0.1, 1.1)))]
    if battery_charge:
        battery_views.append(series_view(CHARGE_ROOT, CHARGE_VIEW_NAME))
    battery = rrb.Vertical(*battery_views, row_shares=[2, 1, 1][:len(battery_views)])
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
