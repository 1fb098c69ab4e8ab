"""``nni-replay`` (``ros2 run nni_msgs_adapter replay``): play a recording back, or view it in Rerun.

ROS playback (the default)::

    nni-replay run.mcap [--rate FACTOR] [--loop] [--start-offset S] [--clock] [--domain-id N]

republishes every recorded topic under its recorded (fully qualified) name with the
QoS its publishers offered (the channel's ``offered_qos_profiles``), spacing the
messages as their ``log_time`` (receive time) was spaced, divided by ``--rate``, as
``ros2 bag play`` does: a lockstep recording therefore replays at the pace it ran
(faster than simulated time), its own ``/clock`` carrying the simulated time.
Messages go out as recorded, CDR bytes untouched. ``--start-offset`` skips the first
S seconds of receive time (the latest latched messages before it still go out first).
``--clock`` also publishes ``/clock`` with the recording's time at 40 Hz, as
``ros2 bag play --clock`` does; a lockstep recording already holds its simulated
``/clock`` and refuses it.

Rerun (no ROS graph; the node module is not even imported)::

    nni-replay run.mcap --rrd out.rrd | --connect [URL|PORT] | --spawn

logs every generator of the recording with :func:`rerun_view.log_trajectory`
and the blueprint of the live view: angle deviation, frequency deviation,
battery power with +-b (b from ``controller/state`` ``battery_limit``), the
saturation flag, W_hat, and the phase portrait with the recorded boundary of
Omega: the same samples, values and labels the live bridge
(:mod:`nni_msgs_adapter.rerun_bridge`) shows. ``--rrd`` writes a file,
``--connect`` streams to a running viewer or server (``rerun``, ``rerun
--serve-web``, default ``rerun+http://127.0.0.1:9876/proxy``), ``--spawn``
starts a native viewer (needs a display). f0 is in no message; ``--f0-hz``
(default 50 Hz) only labels the run parameters.

Bad input (missing, non-MCAP or unrecoverably cut file, a recording without
``plant/state``, an unknown message type or one the contract does not give
the topic, a viewer that is not there, no display for ``--spawn``) prints one
line and exits 2; the ``.rrd`` appears whole or not at all. A recording cut
short (a killed logger) is read up to its last flush.
"""

from __future__ import annotations

import math
import os
import socket
import sys
import urllib.parse
from dataclasses import dataclass, replace

import numpy as np

from nni_msgs_adapter import contract
from nni_msgs_adapter.cli_support import (
    CliError, OneLineParser, atomic_output, finite_float, positive_float, run_cli, writable_output,
)
from nni_msgs_adapter.mcap_io import (
    OfferedQos, RecordedMessage, RecordingError, parse_qos_profiles_yaml, read_messages,
)
from nni_msgs_adapter.recording import (
    GeneratorRun, check_has_plant_state, check_message_type, read_generator_runs, split_topic,
)

PROG = "nni-replay"
APP_ID = "nni_replay"
#: Nominal frequency, Hz: no contract message carries it; the paper's value, as the live bridge's default.
DEFAULT_F0_HZ = 50.0
#: Port of a Rerun viewer's gRPC server when a rerun+http URL names none (Rerun's default).
DEFAULT_VIEWER_PORT = 9876
#: Longest wait for a TCP connection to the viewer (--connect), s.
CONNECT_TIMEOUT_S = 2.0
#: Longest wait for the viewer to take the whole recording (--connect, --spawn), s.
VIEWER_FLUSH_TIMEOUT_S = 30.0
#: Margin around Omega's boundary in the phase portrait's initial bounds (fraction of its extent).
PHASE_MARGIN = 0.15

#: rmw durability policy value (also rclpy's) of latched topics.
_TRANSIENT_LOCAL = 1

_RERUN_URL_SCHEMES = ("rerun", "rerun+http", "rerun+https")

_ROS_ONLY = {"rate": 1.0, "loop": False, "start_offset": 0.0, "clock": False, "wait_for_subscribers": 0,
             "domain_id": None}


# --------------------------------------------------------------------------------------------
# ROS playback plan (pure)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Playback:
    """What a replay publishes, worked out from the file before any ROS call.

    Attributes
    ----------
    topics : dict of str to (str, OfferedQos)
        Topic -> (full message type, QoS to offer), in order of first appearance.
    prelude : list of RecordedMessage
        Latched (transient-local) messages recorded before the start point: published at the
        start of every pass, so late joiners see the state the recording had there.
    timed : list of (int, RecordedMessage)
        The messages from the start point on, in log-time order, each with its recording-time
        offset from the start point, ns.
    start_log_time_ns : int
        Recording time (log time, ns since the epoch) of the start point.
    """

    topics: dict
    prelude: list
    timed: list
    start_log_time_ns: int


def offered_qos(profiles: list[OfferedQos], fallback: OfferedQos) -> OfferedQos:
    """The QoS to offer for a topic's recorded publisher profiles, as rosbag2's player chooses it.

    Profiles that agree on every policy deciding whether a subscriber matches (all but
    history, depth and lifespan): the first of them, with the history and depth of
    ``fallback``, since the graph does not show a publisher's history (the logger records
    ``unknown``, depth 0, as rosbag2 does). No profile, or disagreeing ones: ``fallback``.
    """
    if not profiles:
        return fallback
    first = profiles[0]
    matching = ("reliability", "durability", "deadline_ns", "liveliness", "liveliness_lease_duration_ns")
    if any(getattr(profile, name) != getattr(first, name) for profile in profiles for name in matching):
        return fallback
    return replace(first, history=fallback.history, depth=fallback.depth)


def plan_playback(path, messages: list[RecordedMessage], start_offset_s: float = 0.0) -> Playback:
    """Topics, QoS and timing of a replay of ``messages`` (as :func:`mcap_io.read_messages` yields them).

    Raises
    ------
    RecordingError
        If a message type is unknown, a contract topic has another type, a QoS description is
        invalid, or there is no ``plant/state``.
    CliError
        If ``start_offset_s`` is past the last message.
    """
    topics: dict[str, tuple[str, OfferedQos]] = {}
    for record in messages:
        if record.topic not in topics:
            check_message_type(path, record)
            split = split_topic(record.topic)
            # The contract's QoS on its topics; rosbag2's default (keep-last 10, reliable, volatile) elsewhere.
            fallback = OfferedQos.from_rclpy(contract.TOPICS[split[1]][2]) if split else OfferedQos()
            topics[record.topic] = (record.type_name, offered_qos(parse_qos_profiles_yaml(record.qos_yaml), fallback))
    check_has_plant_state(path, topics)
    ordered = sorted(messages, key=lambda record: record.log_time_ns)  # stable: per-topic order kept
    start_ns = ordered[0].log_time_ns + round(start_offset_s * 1e9)
    if start_ns > ordered[-1].log_time_ns:
        length_s = (ordered[-1].log_time_ns - ordered[0].log_time_ns) * 1e-9
        raise CliError(f"start offset {start_offset_s:g} s is past the end of the recording ({length_s:.3f} s long)")
    latest_latched: dict[str, RecordedMessage] = {}
    timed = []
    for record in ordered:
        if record.log_time_ns >= start_ns:
            timed.append((record.log_time_ns - start_ns, record))
        elif topics[record.topic][1].durability == _TRANSIENT_LOCAL:
            latest_latched[record.topic] = record
    return Playback(topics, list(latest_latched.values()), timed, start_ns)


# --------------------------------------------------------------------------------------------
# Rerun conversion
# --------------------------------------------------------------------------------------------


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


def log_recording(stream, runs, f0_hz: float = DEFAULT_F0_HZ) -> None:
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
        Nominal frequency, Hz (run parameters only).
    """
    from nni_msgs_adapter.rerun_view import log_trajectory

    for run in runs:
        answered = run.answered
        signals = {name: values[answered] for name, values in run.signals.items()}
        log_trajectory(stream, run_label(run), run.t_s[answered], signals["angle_dev"], run.speed_rad_s[answered],
                       signals["battery_power"], signals["saturated"], signals["w_hat"], run.battery_limit_pu,
                       f0_hz, run.omega_boundary)


def viewable_runs(path, runs: dict[str, GeneratorRun]) -> list[GeneratorRun]:
    """The runs with answered samples; RecordingError if there is none (a plant without controller)."""
    viewable = [run for run in runs.values() if run.answered.any()]
    if not viewable:
        raise RecordingError(f"{path}: no {contract.TOPIC_CONTROLLER_STATE} answers a {contract.TOPIC_PLANT_STATE}: "
                             "no battery limit or angle deviation to show")
    return viewable


def convert(args) -> int:
    """``--rrd`` / ``--connect`` / ``--spawn``: the recording in Rerun, with the blueprint."""
    runs = viewable_runs(args.recording, read_generator_runs(args.recording))
    if args.spawn:
        check_display()
    elif args.connect is not None:
        check_listening(args.connect)
    import rerun as rr

    from nni_msgs_adapter.rerun_view import blueprint, open_recording

    layout = blueprint(phase_bounds=phase_bounds(runs))
    if args.rrd is not None:
        # In memory first, so that the .rrd appears whole or not at all (atomic rename).
        stream = rr.RecordingStream(APP_ID)
        memory = stream.memory_recording()
        stream.send_blueprint(layout)
        log_recording(stream, runs, args.f0_hz)
        stream.flush()
        with atomic_output(args.rrd, "wb") as handle:
            handle.write(memory.drain_as_bytes())
        print(f"{PROG}: wrote {args.rrd} ({len(runs)} generator run(s))")
        return 0
    # rerun_bindings raises RuntimeError for a viewer that cannot be reached or started.
    try:
        if args.connect is not None:
            stream = rr.RecordingStream(APP_ID)
            stream.connect_grpc(args.connect)
            stream.send_blueprint(layout)
        else:
            stream, _ = open_recording(APP_ID, ("spawn", None), layout=layout)
        log_recording(stream, runs, args.f0_hz)
        stream.flush(timeout_sec=VIEWER_FLUSH_TIMEOUT_S)
    except RuntimeError as error:
        raise CliError(f"Rerun viewer: {str(error).splitlines()[0]}") from None
    stream.disconnect()
    print(f"{PROG}: sent {len(runs)} generator run(s) to {args.connect or 'a spawned viewer'}")
    return 0


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
    from nni_msgs_adapter.rerun_view import display_missing

    if display_missing():
        raise CliError("--spawn needs a display (DISPLAY and WAYLAND_DISPLAY are unset): "
                       "write --rrd OUT.rrd, or stream with --connect URL to a viewer elsewhere")


# --------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    import argparse

    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def build_parser() -> OneLineParser:
    """The nni-replay command line."""
    parser = OneLineParser(prog=PROG, description="Replay an NNI MCAP recording on ROS 2, or view it in Rerun.")
    parser.add_argument("recording", help="MCAP file (ROS 2 profile), e.g. recordings/paper_b0.3.mcap")
    ros = parser.add_argument_group("ROS playback (default)")
    ros.add_argument("--rate", type=positive_float, default=1.0, help="speed factor (2: twice as fast)")
    ros.add_argument("--loop", action="store_true", help="start again after the last message, until stopped")
    ros.add_argument("--start-offset", type=non_negative_float, default=0.0, metavar="S",
                     help="skip the first S seconds of the recording (latched topics still go out)")
    ros.add_argument("--clock", action="store_true", help="publish /clock with the recording's time at 40 Hz")
    ros.add_argument("--wait-for-subscribers", type=int, default=0, metavar="N",
                     help="start once every replayed topic has N subscribers (default 0: at once)")
    ros.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: the environment's)")
    view = parser.add_argument_group("Rerun instead of ROS")
    sink = view.add_mutually_exclusive_group()
    sink.add_argument("--rrd", type=writable_output, metavar="OUT.rrd", help="write a Rerun recording file")
    sink.add_argument("--connect", metavar="URL", type=connect_url, nargs="?",
                      const=f"rerun+http://127.0.0.1:{DEFAULT_VIEWER_PORT}/proxy",
                      help="stream to a running viewer or server: its gRPC URL or port "
                           f"(default rerun+http://127.0.0.1:{DEFAULT_VIEWER_PORT}/proxy)")
    sink.add_argument("--spawn", action="store_true", help="start a native viewer and stream to it")
    view.add_argument("--f0-hz", type=positive_float, default=DEFAULT_F0_HZ,
                      help="nominal frequency for the run parameters, Hz (default 50: not in the recording)")
    return parser


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """``(own arguments, ROS arguments)``: ``--ros-args ... [--]`` is rclpy's (as ``ros2 run`` passes it)."""
    own, ros, in_ros = [], [], False
    for arg in argv:
        if arg == "--ros-args":
            in_ros = True
        elif in_ros and arg == "--":
            in_ros = False
            continue
        (ros if in_ros else own).append(arg)
    return own, ros


def play(args, ros_args: list[str]) -> int:
    """ROS playback: read and plan first (bad input never starts ROS), then spin the node."""
    messages = list(read_messages(args.recording))
    playback = plan_playback(args.recording, messages, args.start_offset)
    if args.clock and contract.TOPIC_CLOCK in playback.topics:
        raise CliError(f"{args.recording} already holds {contract.TOPIC_CLOCK} (a lockstep run): "
                       "replay it without --clock")
    if args.domain_id is not None:
        if not 0 <= args.domain_id <= 232:
            raise CliError(f"ROS domain id must be within 0..232, got {args.domain_id}")
        os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
    from nni_msgs_adapter.node_main import run_node
    from nni_msgs_adapter.replay_node import ReplayNode

    return run_node(lambda: ReplayNode(playback, rate=args.rate, loop=args.loop, clock=args.clock,
                                       wait_for_subscribers=args.wait_for_subscribers),
                    [PROG, *ros_args], prog=PROG)


def main(argv=None) -> int:
    """Entry point of ``nni-replay`` and ``ros2 run nni_msgs_adapter replay``."""
    own, ros_args = split_ros_args(sys.argv[1:] if argv is None else list(argv))
    parser = build_parser()

    def body() -> int:
        args = parser.parse_args(own)
        if args.wait_for_subscribers < 0:
            raise CliError(f"--wait-for-subscribers must be >= 0, got {args.wait_for_subscribers}")
        if args.rrd is not None or args.connect is not None or args.spawn:
            misplaced = [name for name, default in _ROS_ONLY.items() if getattr(args, name) != default]
            if misplaced or ros_args:
                options = ", ".join("--" + name.replace("_", "-") for name in misplaced) or "--ros-args"
                raise CliError(f"{options}: ROS playback options, not for --rrd/--connect/--spawn")
            return convert(args)
        return play(args, ros_args)

    return run_cli(body, PROG)


if __name__ == "__main__":
    sys.exit(main())
