"""``nni-replay --rrd | --connect | --spawn``: the recording in Rerun (no ROS graph; the node module is not even imported).

::

    nni-replay run.mcap --rrd out.rrd | --connect [URL|PORT] | --spawn

It logs every generator of the recording with :func:`rerun_trajectory.log_trajectory`
and the blueprint of the live view: angle deviation, frequency deviation,
battery power with +-b (b from ``controller/state`` ``battery_limit``), the
saturation flag, W_hat, and the phase portrait with the recorded boundary of
Omega: the same samples, values and labels the live bridge
(:mod:`nni_msgs_adapter.viewing.rerun_bridge`) shows. ``--rrd`` writes a file,
``--connect`` streams to a running viewer or server (``rerun``, ``rerun
--serve-web``, default ``rerun+http://127.0.0.1:9876/proxy``), ``--spawn``
starts a native viewer (needs a display). f0 comes from the recording's run
parameters (the ``nni_run`` metadata); ``--f0-hz`` labels a recording made
before they were recorded, and is refused for one that has them. A network run
(its run parameters name its ``case``, :mod:`network_runs`) is shown in the
network layout instead: per generator ``gen<i>``, its angle relative to the
centre of inertia, frequency, battery power with +-b and saturation, one colour
each, as the bridge shows it with ``namespaces``; f0 is the case's.
"""

from __future__ import annotations

import math
import socket
import urllib.parse

import numpy as np

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.cli_support import CliError, atomic_output
from nni_msgs_adapter.recording.mcap_io import RecordingError
from nni_msgs_adapter.recording.network_runs import CASE_KEY
from nni_battery_controller.replay_load import PROG, load, readable_runs, recorded_network, warn
from nni_msgs_adapter.recording.runs import GeneratorRun, run_metadata
from nni_msgs_adapter.viewing.bridge_protocol import display_missing
from nni_plant_sim.battery import charge_over

#: Port of a Rerun viewer's gRPC server when a rerun+http URL names none (Rerun's default).
DEFAULT_VIEWER_PORT = 9876
#: Longest wait for a TCP connection to the viewer (--connect), s.
CONNECT_TIMEOUT_S = 2.0
#: Longest wait for the viewer to take the whole recording (--connect, --spawn), s.
VIEWER_FLUSH_TIMEOUT_S = 30.0
#: Margin around Omega's boundary in the phase portrait's initial bounds (fraction of its extent).
PHASE_MARGIN = 0.15

_RERUN_URL_SCHEMES = ("rerun", "rerun+http", "rerun+https")


def connect_url(text: str) -> str:
    """argparse type for ``--connect``: a Rerun gRPC proxy URL, or a port on this machine.

    ``9876`` -> ``rerun+http://127.0.0.1:9876/proxy`` (as ``rerun --connect`` expands it).
    """
    import argparse

    if text.isdigit():
        text = f"rerun+http://127.0.0.1:{text}/proxy"
    parts = urllib.parse.urlsplit(text)
    try:
        port = parts.port
    except ValueError:
        port = -1
    if parts.scheme not in _RERUN_URL_SCHEMES or not parts.hostname or port == -1 or parts.path != "/proxy":
        raise argparse.ArgumentTypeError(
            f"expected a port or a URL like rerun+http://127.0.0.1:9876/proxy "
            f"(scheme {', '.join(_RERUN_URL_SCHEMES)}, path /proxy), got {text!r}")
    return text


def check_listening(url: str) -> None:
    """CliError unless something accepts TCP connections at the URL's host and port.

    Rerun's SDK would otherwise retry in the background and fail only at the final flush.
    """
    parts = urllib.parse.urlsplit(url)
    port = parts.port or (443 if parts.scheme != "rerun+http" else DEFAULT_VIEWER_PORT)
    try:
        socket.create_connection((parts.hostname, port), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as error:
        raise CliError(f"no Rerun viewer listening at {url} ({error.strerror or error}): "
                       "start one (`rerun`, or `rerun --serve-web` on a headless machine), or write --rrd OUT.rrd") from None


def check_display() -> None:
    """CliError if a native viewer cannot open a window here."""
    if display_missing():
        raise CliError("--spawn needs a display (DISPLAY and WAYLAND_DISPLAY are unset): "
                       "write --rrd OUT.rrd, or stream with --connect URL to a viewer elsewhere")


def run_label(run: GeneratorRun) -> str:
    """Label of a generator in the views: ``b=0.3`` as the live bridge labels it, ``gen1 b=0.3`` in namespace /gen1."""
    b = run.battery_limit_pu
    label = "b=inf" if math.isinf(b) else f"b={b:g}"
    return f"{run.namespace.lstrip('/')} {label}" if run.namespace else label


def phase_bounds(runs) -> tuple | None:
    """Initial phase-portrait bounds: every recorded Omega boundary with a margin; None if none."""
    boundaries = [run.omega_boundary for run in runs if run.omega_boundary is not None]
    if not boundaries:
        return None
    points = np.vstack(boundaries)
    lo, hi = points.min(axis=0), points.max(axis=0)
    margin = PHASE_MARGIN * (hi - lo)
    return ((lo[0] - margin[0], hi[0] + margin[0]), (lo[1] - margin[1], hi[1] + margin[1]))


def recorded_energy_pu_s(parameters: dict | None) -> float:
    """The batteries' energy as the recording's run parameters say (the SMIB plant's or the network plant's, one
    for every generator), pu s of each machine's rating (inf: unlimited, or not recorded)."""
    plant = (parameters or {}).get("plant") or (parameters or {}).get("network_plant") or {}
    return float(plant.get("battery_energy_pu_s", math.inf))


def recorded_charge(t_s, given_pu, answered, energy_pu_s: float):
    """A battery's charge at the ``answered`` instants from the powers it gave (None for an unlimited one)."""
    return None if math.isinf(energy_pu_s) else np.asarray(charge_over(t_s, given_pu, energy_pu_s))[answered]


def log_recording(stream, runs, f0_hz: float, energy_pu_s: float = math.inf) -> None:
    """Log generator runs on a Rerun stream (the blueprint is the caller's).

    The samples are those the controller answered, with the values the live bridge shows:
    angle deviation, battery power, saturation and W_hat from ``controller/state``, the speed
    deviation from ``plant/state`` at the same stamp. Time runs from the run's first state.

    Parameters
    ----------
    stream : rerun.RecordingStream
        Target.
    runs : iterable of GeneratorRun
        Runs with at least one answered sample (see :func:`viewable_runs`).
    f0_hz : float
        Nominal frequency, Hz (run parameters only; NaN when the recording does not say).
    energy_pu_s : float
        The battery's energy (finite: its charge is drawn, from the powers the plant's states say it gave,
        :func:`nni_plant_sim.battery.charge_over`).
    """
    from nni_msgs_adapter.viewing.rerun_trajectory import log_trajectory

    for run in runs:
        answered = run.answered
        signals = {name: values[answered] for name, values in run.signals.items()}
        charge = recorded_charge(run.t_s, run.battery_power_pu, answered, energy_pu_s)
        log_trajectory(stream, run_label(run), run.t_s[answered], signals["angle_dev"], run.speed_rad_s[answered],
                       signals["battery_power"], signals["saturated"], signals["w_hat"], run.battery_limit_pu,
                       f0_hz, run.omega_boundary, battery_charge_pu_s=charge)


def log_network(stream, network, energy_pu_s: float = math.inf) -> None:
    """Log a network run on a Rerun stream, generator by generator (label ``gen<i>``), in the network layout.

    Each generator's samples are the instants its controller answered (as for a SMIB run),
    its angle relative to the centre of inertia of every generator's angle at that instant; with a finite
    ``energy_pu_s`` (every battery's) its battery's charge.
    """
    from nni_msgs_adapter.viewing.palette import generator_colour_rgb
    from nni_msgs_adapter.viewing.rerun_layout import NETWORK_VIEW
    from nni_msgs_adapter.viewing.rerun_trajectory import log_trajectory

    angles = network.coi_angle_rad()
    for i, namespace in enumerate(network.namespaces):
        answered = network.answered[:, i]
        if not answered.any():
            warn(f"{namespace}: its controller answered no sample: not shown")
            continue
        log_trajectory(stream, namespace.lstrip("/"), network.t_s[answered], angles[answered, i],
                       network.speed_rad_s[answered, i], network.commanded_power_pu[answered, i],
                       network.saturated[answered, i], None, float(network.limits_pu[i]), float(network.net.f0_hz),
                       color=generator_colour_rgb(i), kind=NETWORK_VIEW,
                       battery_charge_pu_s=recorded_charge(network.t_s, network.battery_power_pu[:, i], answered,
                                                           energy_pu_s))


def viewable_runs(path, runs: dict[str, GeneratorRun]) -> list[GeneratorRun]:
    """The runs with answered samples; RecordingError if there is none (a plant without controller)."""
    viewable = [run for run in runs.values() if run.answered.any()]
    if not viewable:
        raise RecordingError(f"{path}: no {contract.TOPIC_CONTROLLER_STATE} answers a {contract.TOPIC_PLANT_STATE}: "
                             "no battery limit or angle deviation to show")
    return viewable


def view_f0_hz(args, parameters: dict | None) -> float:
    """f0 for the Rerun view: the recorded plant's; ``--f0-hz`` only for a recording that does not say."""
    recorded = (parameters or {}).get("plant", {}).get("f0_hz")
    if recorded is not None:
        if args.f0_hz is not None:
            raise CliError(f"--f0-hz: {args.recording} records f0 = {recorded:g} Hz; "
                           "the option only labels recordings without run parameters")
        return float(recorded)
    if args.f0_hz is None:
        warn(f"{args.recording} holds no run parameters (no nni_run metadata): f0 is shown as NaN; "
             "--f0-hz HZ labels it")
        return math.nan
    return args.f0_hz


def convert(args) -> int:
    """``--rrd`` / ``--connect`` / ``--spawn``: the recording in Rerun, with the blueprint."""
    recording = load(args)
    every_run = readable_runs(recording)
    runs = viewable_runs(args.recording, every_run)
    parameters = run_metadata(recording)
    network = recorded_network(recording, every_run, parameters)
    if args.spawn:
        check_display()
    elif args.connect is not None:
        check_listening(args.connect)
    from nni_msgs_adapter.viewing.rerun_layout import NETWORK_VIEW, blueprint
    from nni_msgs_adapter.viewing.rerun_stream import APP_ID, open_recording, recording_stream

    energy_pu_s = recorded_energy_pu_s(parameters)
    if network is None:
        f0_hz = view_f0_hz(args, parameters)
        layout = blueprint(phase_bounds=phase_bounds(runs), battery_charge=not math.isinf(energy_pu_s))

        def log(stream) -> None:
            log_recording(stream, runs, f0_hz, energy_pu_s)
    else:
        if args.f0_hz is not None:
            raise CliError(f"--f0-hz: {args.recording} is a run of case {parameters[CASE_KEY]} "
                           f"(f0 = {network.net.f0_hz:g} Hz); the option only labels recordings without run parameters")
        layout = blueprint(kind=NETWORK_VIEW, battery_charge=not math.isinf(energy_pu_s))

        def log(stream) -> None:
            log_network(stream, network, energy_pu_s)
    if args.rrd is not None:
        # In memory first, so that the .rrd appears whole or not at all (atomic rename).
        stream = recording_stream()
        memory = stream.memory_recording()
        stream.send_blueprint(layout)
        log(stream)
        stream.flush()
        with atomic_output(args.rrd, "wb") as handle:
            handle.write(memory.drain_as_bytes())
        print(f"{PROG}: wrote {args.rrd} ({len(runs)} generator run(s))")
        return 0
    # rerun_bindings raises RuntimeError for a viewer that cannot be reached or started.
    try:
        sink = ("connect", args.connect) if args.connect is not None else ("spawn", None)
        stream, _ = open_recording(APP_ID, sink, layout=layout)
        log(stream)
        stream.flush(timeout_sec=VIEWER_FLUSH_TIMEOUT_S)
    except RuntimeError as error:
        raise CliError(f"Rerun viewer: {str(error).splitlines()[0]}") from None
    stream.disconnect()
    print(f"{PROG}: sent {len(runs)} generator run(s) to {args.connect or 'a spawned viewer'}")
    return 0
