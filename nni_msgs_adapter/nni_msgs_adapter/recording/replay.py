"""``nni-replay`` (``ros2 run nni_msgs_adapter replay``): play a recording back, view it, describe it.

ROS playback (the default)::

    nni-replay run.mcap [--rate FACTOR] [--loop] [--start-offset S] [--clock]
                        [--wait-for-subscribers N] [--wait-topic TOPIC] [--domain-id N]

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

Playback starts once N subscribers (``--wait-for-subscribers``, default 1) listen to the
replayed topics, each matched on every replayed topic it subscribes to (a subscriber of one
topic counts; it is not asked to subscribe to all of them), and discovery has then settled
(:mod:`replay_node`); ``--wait-topic TOPIC`` counts only the subscribers of that topic. ``0``
starts at once, publishing whether anyone listens or not. While it waits it says so on its log.

Rerun (no ROS graph; the node module is not even imported)::

    nni-replay run.mcap --rrd out.rrd | --connect [URL|PORT] | --spawn

logs every generator of the recording with :func:`rerun_trajectory.log_trajectory`
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

Description and figure (no ROS graph)::

    nni-replay run.mcap --info            # what `ros2 bag info` shows, the run's parameters, its verdicts
    nni-replay run.mcap --plot out.png    # the run's figure (nni-simulate's, from the recorded samples)

``--info`` prints the file, its size, ROS distro, duration, start and end, message count,
each topic's type, count, serialization format and QoS, whether the file is complete, the
run's parameters key by key and, per generator, one block (its samples, b, the largest
battery power applied, the trust counters of the plant's last ``gen<i>/plant`` status) followed by
the verdicts of :func:`nni_battery_controller.simulate.assess` key by key; for a network run (the
parameters name its ``case``) the verdicts of :func:`nni_battery_controller.network_sim.assess_network`,
the system's first, then each generator's. Verdicts and ``--plot`` need the
run's parameters (the plant's equilibrium and the controller's limit): a recording without
them is refused for those with one line. ``--plot`` draws single-machine runs only.

A recording cut short (a killed logger, a full disk) is read up to its last flush and
reported as incomplete (how many messages, up to which time): ``--info`` says so, every
other use refuses it unless ``--allow-partial``. Bad input (missing, non-regular,
non-MCAP, oversized or unrecoverably cut file, a recording without ``plant/state``, an
unknown message type or one the contract does not give the topic, a viewer that is not
there, no display for ``--spawn``) prints one line and exits 2; the ``.rrd`` appears whole
or not at all.
"""

from __future__ import annotations

import dataclasses
import datetime
import math
import os
import socket
import sys
import urllib.parse
from dataclasses import dataclass, replace

import numpy as np

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.cli_support import (
    CliError, OneLineParser, atomic_output, finite_float, positive_float, run_cli, writable_output,
)
from nni_msgs_adapter.recording.mcap_io import (
    OfferedQos, RecordedMessage, Recording, RecordingError, parse_qos_profiles_yaml, read_recording,
)
from nni_msgs_adapter.recording.network_runs import CASE_KEY, namespace_order, network_run, recorded_case
from nni_msgs_adapter.recording.runs import (
    GeneratorRun, check_has_plant_state, check_message_type, generator_runs, run_metadata, sampled_trajectory,
    split_topic,
)

PROG = "nni-replay"
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

#: Subscribers a playback waits for by default: someone must listen (see the module docstring).
DEFAULT_WAIT_FOR_SUBSCRIBERS = 1

_ROS_ONLY = {"rate": 1.0, "loop": False, "start_offset": 0.0, "clock": False,
             "wait_for_subscribers": DEFAULT_WAIT_FOR_SUBSCRIBERS, "wait_topic": None, "domain_id": None}
_RERUN_ONLY = {"f0_hz": None}


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


def log_recording(stream, runs, f0_hz: float) -> None:
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
    """
    from nni_msgs_adapter.viewing.rerun_trajectory import log_trajectory

    for run in runs:
        answered = run.answered
        signals = {name: values[answered] for name, values in run.signals.items()}
        log_trajectory(stream, run_label(run), run.t_s[answered], signals["angle_dev"], run.speed_rad_s[answered],
                       signals["battery_power"], signals["saturated"], signals["w_hat"], run.battery_limit_pu,
                       f0_hz, run.omega_boundary)


def log_network(stream, network) -> None:
    """Log a network run on a Rerun stream, generator by generator (label ``gen<i>``), in the network layout.

    Each generator's samples are the instants its controller answered (as for a SMIB run),
    its angle relative to the centre of inertia of every generator's angle at that instant.
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
                       color=generator_colour_rgb(i), kind=NETWORK_VIEW)


def viewable_runs(path, runs: dict[str, GeneratorRun]) -> list[GeneratorRun]:
    """The runs with answered samples; RecordingError if there is none (a plant without controller)."""
    viewable = [run for run in runs.values() if run.answered.any()]
    if not viewable:
        raise RecordingError(f"{path}: no {contract.TOPIC_CONTROLLER_STATE} answers a {contract.TOPIC_PLANT_STATE}: "
                             "no battery limit or angle deviation to show")
    return viewable


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

    if network is None:
        f0_hz = view_f0_hz(args, parameters)
        layout = blueprint(phase_bounds=phase_bounds(runs))

        def log(stream) -> None:
            log_recording(stream, runs, f0_hz)
    else:
        if args.f0_hz is not None:
            raise CliError(f"--f0-hz: {args.recording} is a run of case {parameters[CASE_KEY]} "
                           f"(f0 = {network.net.f0_hz:g} Hz); the option only labels recordings without run parameters")
        layout = blueprint(kind=NETWORK_VIEW)

        def log(stream) -> None:
            log_network(stream, network)
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
        if args.connect is not None:
            stream = recording_stream()
            stream.connect_grpc(args.connect)
            stream.send_blueprint(layout)
        else:
            stream, _ = open_recording(APP_ID, ("spawn", None), layout=layout)
        log(stream)
        stream.flush(timeout_sec=VIEWER_FLUSH_TIMEOUT_S)
    except RuntimeError as error:
        raise CliError(f"Rerun viewer: {str(error).splitlines()[0]}") from None
    stream.disconnect()
    print(f"{PROG}: sent {len(runs)} generator run(s) to {args.connect or 'a spawned viewer'}")
    return 0


def warn(text: str) -> None:
    """A warning line on stderr (the run goes on)."""
    print(f"{PROG}: warning: {text}", file=sys.stderr, flush=True)


def load(args, *, whole: bool = True) -> Recording:
    """The recording, with what is wrong with it said: refused if cut short, unless ``--allow-partial`` (or not ``whole``)."""
    recording = read_recording(args.recording)
    if recording.duplicate_chunks:
        warn(f"{args.recording}: {recording.duplicate_chunks} chunk(s) repeat an earlier one: each read once")
    if not recording.complete:
        if whole and not args.allow_partial:
            raise CliError(f"{recording.incompleteness()}; refused: --allow-partial uses what it holds")
        warn(recording.incompleteness())
    return recording


def readable_runs(recording: Recording) -> dict[str, GeneratorRun]:
    """The recording's generator runs; each sample left out (a malformed message) said on stderr."""
    runs = generator_runs(recording)
    for run in runs.values():
        for line in run.skipped:
            warn(f"{recording.path}: sample left out: {line}")
    return runs


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


def require_parameters(recording: Recording, what: str) -> dict:
    """The run's parameters, or CliError naming what needs them."""
    parameters = run_metadata(recording)
    if parameters is None:
        raise CliError(f"{recording.path} holds no run parameters (no nni_run metadata: recorded before they were, "
                       f"or by a logger started without run_metadata): {what} needs them")
    return parameters


def _dataclass_from(cls, values, section: str, path) -> object:
    """``cls`` from the recorded section's values, every field present (none silently defaulted)."""
    if not isinstance(values, dict):
        raise CliError(f"{path}: run parameters hold no {section!r} section")
    names = [f.name for f in dataclasses.fields(cls)]
    missing = [name for name in names if name not in values]
    if missing:
        raise CliError(f"{path}: run parameters lack {section}.{', '.join(missing)}")
    try:
        return cls(**{name: float(values[name]) for name in names})
    except (TypeError, ValueError) as error:
        raise CliError(f"{path}: recorded {section} parameters are invalid: {error}") from None


def recorded_scenario(parameters: dict, path) -> tuple:
    """The run's scenario as an object and as ``{"name": ..., <its values>}``, from the recorded plant parameters."""
    from nni_plant_sim.scenarios import SCENARIO_FIELDS, from_values

    plant = parameters.get("plant")
    try:
        scenario = from_values(plant)
        return scenario, {"name": plant["scenario"], **{k: plant[k] for k in SCENARIO_FIELDS[plant["scenario"]]}}
    except (KeyError, TypeError, ValueError) as error:
        raise CliError(f"{path}: the recorded plant parameters name no valid scenario ({error})") from None


def recorded_setting(parameters: dict, key: str, path):
    """One top-level run parameter (mode, rate_hz), or CliError naming it."""
    if key not in parameters:
        raise CliError(f"{path}: run parameters lack {key!r}")
    return parameters[key]


def trajectories(recording: Recording, runs: dict[str, GeneratorRun], parameters: dict) -> dict:
    """Per namespace, the run as a sampled :class:`simulate.Trajectory` with the recorded parameters.

    b is the one the controller reported in the run (``controller/state``), where it did.
    """
    from nni_battery_controller.law import ControllerParams
    from nni_plant_sim.model import SmibParams

    plant = _dataclass_from(SmibParams, parameters.get("plant"), "plant", recording.path)
    ctrl = _dataclass_from(ControllerParams, parameters.get("controller"), "controller", recording.path)
    out = {}
    for namespace, run in runs.items():
        b = run.battery_limit_pu
        run_ctrl = ctrl if math.isnan(b) else replace(ctrl, battery_limit_pu=b)
        out[namespace] = sampled_trajectory(run, plant, run_ctrl)
    return out


def _time_text(ns: int) -> str:
    stamp = datetime.datetime.fromtimestamp(ns / 1e9, tz=datetime.timezone.utc)
    return f"{stamp:%b %d %Y %H:%M:%S}.{ns % 1_000_000_000:09d} UTC ({ns // 1_000_000_000}.{ns % 1_000_000_000:09d})"


def info_lines(recording: Recording, runs: dict[str, GeneratorRun], parameters: dict | None) -> list[str]:
    """What ``--info`` prints: ``ros2 bag info``'s fields, completeness, parameters, verdicts."""
    from nni_msgs_adapter.recording.mcap_io import describe_qos

    from nni_battery_controller.simulate import assess

    messages = recording.messages
    first, last = messages[0].log_time_ns, messages[-1].log_time_ns
    rosbag2 = recording.metadata.get("rosbag2", {})
    topics: dict[str, list] = {}
    for record in messages:
        topics.setdefault(record.topic, [record.type_name, 0, record.qos_yaml])[1] += 1
    size = recording.path.stat().st_size
    lines = [
        f"Files:             {recording.path.name}",
        f"Bag size:          {size / 1024:.1f} KiB",
        "Storage id:        mcap",
        f"ROS Distro:        {rosbag2.get('ROS_DISTRO', 'unknown')}",
        f"Duration:          {(last - first) * 1e-9:.9f}s",
        f"Start:             {_time_text(first)}",
        f"End:               {_time_text(last)}",
        f"Messages:          {len(messages)}",
    ]
    for index, (topic, (type_name, count, qos_yaml)) in enumerate(sorted(topics.items())):
        qos = "; ".join(describe_qos(profile) for profile in parse_qos_profiles_yaml(qos_yaml)) or "not recorded"
        lines.append(f"{'Topic information: ' if index == 0 else ' ' * 19}Topic: {topic} | Type: {type_name} | "
                     f"Count: {count} | Serialization Format: cdr | QoS: {qos}")
    lines.append(f"Complete:          {'yes' if recording.complete else 'no: ' + recording.incompleteness()}")
    if parameters is None:
        lines.append("Run parameters:    not recorded (no nni_run metadata): no verdicts")
        verdicts = {}
    else:
        lines.append("Run parameters:")
        lines += [f"  {key}: {json_text(value)}" for key, value in parameters.items()]
        network = recorded_network(recording, runs, parameters)
        if network is None:
            scenario, _ = recorded_scenario(parameters, recording.path)
            verdicts = {namespace: assess(traj, scenario=scenario).to_json()
                        for namespace, traj in trajectories(recording, runs, parameters).items()}
        else:
            verdicts = network_verdicts(network)
            lines.append(f"Verdicts of the network ({parameters[CASE_KEY]}, {network.stamp_ns.size} instants "
                         "every generator reported):")
            lines += [f"  {key}: {json_text(value)}" for key, value in verdicts.pop("").items()]
    for namespace, run in sorted(runs.items(), key=lambda item: namespace_order(item[0])):
        lines += generator_lines(namespace, run)
        if namespace in verdicts:
            lines.append(f"Verdicts{' of ' + namespace if namespace else ''}:")
            lines += [f"  {key}: {json_text(value)}" for key, value in verdicts[namespace].items()]
    return lines


#: Diagnostics keys of the plant's status that count what it did not trust or could not do, in this order.
TRUST_COUNTERS = ("foreign_commands", "unsolicited_commands", "expired_commands", "invalid_commands",
                  "clipped_commands", "writer_alarms", "stand_down_commands", "re_pairings", "deadline_misses",
                  "command_timeouts")


def generator_lines(namespace: str, run: GeneratorRun) -> list[str]:
    """One generator's block of ``--info``: its samples, b, the largest battery power, the plant's trust counters."""
    answered = int(run.answered.sum())
    machine = run.diagnostics.get("machine")
    b = run.battery_limit_pu
    lines = [f"Generator{' ' + namespace if namespace else ''}{f' (machine {machine})' if machine else ''}:",
             f"  samples: {run.stamp_ns.size} plant states, {answered} answered by the controller",
             f"  battery limit b: {'not reported' if math.isnan(b) else f'{b:g} pu'}",
             f"  max|P_ST|: {float(np.max(np.abs(run.battery_power_pu))):.6g} pu (applied, recorded plant states)"]
    counters = [f"{key} {run.diagnostics[key]}" for key in TRUST_COUNTERS if key in run.diagnostics]
    lines.append(f"  trust (plant diagnostics, last status): {', '.join(counters)}" if counters
                 else "  trust: no plant diagnostics recorded for this generator")
    return lines


def recorded_network(recording: Recording, runs: dict[str, GeneratorRun], parameters: dict | None):
    """The recording as a :class:`network_runs.NetworkRun` if its parameters name a case; None otherwise."""
    from nni_plant_sim.cases import load_network

    try:
        case = recorded_case(parameters)
        return None if case is None else network_run(load_network(case), runs)
    except ValueError as error:
        raise CliError(f"{recording.path}: {error}") from None


def network_verdicts(network) -> dict:
    """``{"": the system's verdicts, namespace: that generator's}`` of :func:`network_sim.assess_network`."""
    from nni_battery_controller.network_sim import assess_network

    outcome = assess_network(network.trajectory())[0].to_json()
    generators = outcome.pop("generators")
    return {"": outcome, **dict(zip(network.namespaces, generators))}


def json_text(value) -> str:
    """A parameter or verdict value as JSON text (``inf`` as JSON's Infinity, as recorded)."""
    import json

    return json.dumps(value)


def describe(args) -> int:
    """``--info``: print what the recording holds (complete or not: it says which)."""
    recording = load(args, whole=False)
    runs = readable_runs(recording)
    print("\n".join(info_lines(recording, runs, run_metadata(recording))))
    return 0


def plot(args) -> int:
    """``--plot OUT.png``: the run's figure, as ``nni-simulate --plot`` draws it, from the recorded samples."""
    from nni_battery_controller.cli import plot_runs
    from nni_battery_controller.simulate import assess

    recording = load(args)
    runs = readable_runs(recording)
    parameters = require_parameters(recording, "--plot")
    if recorded_network(recording, runs, parameters) is not None:
        raise CliError(f"--plot draws single-machine runs; {args.recording} is a run of case {parameters[CASE_KEY]}: "
                       "view it with --rrd OUT.rrd (or --info for its verdicts)")
    trajs = list(trajectories(recording, runs, parameters).values())
    scenario, scenario_values = recorded_scenario(parameters, recording.path)
    outcomes = [assess(traj, scenario=scenario).to_json() for traj in trajs]
    rate_hz = recorded_setting(parameters, "rate_hz", recording.path)
    plot_runs(trajs, outcomes, args.plot, scenario_values, f"sampled at {rate_hz:g} Hz",
              recorded_setting(parameters, "mode", recording.path))
    print(f"{PROG}: wrote {args.plot} ({len(trajs)} generator run(s))")
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
    from nni_msgs_adapter.viewing.rerun_stream import display_missing

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
    parser = OneLineParser(prog=PROG, description="Replay an NNI MCAP recording on ROS 2, view it in Rerun, "
                                                  "describe it or draw its figure.")
    parser.add_argument("recording", help="MCAP file (ROS 2 profile), e.g. recordings/paper_b0.3.mcap")
    parser.add_argument("--allow-partial", action="store_true",
                        help="use a recording cut short (killed logger, full disk) up to its last flush "
                             "(default: refused; --info always describes it)")
    ros = parser.add_argument_group("ROS playback (default)")
    ros.add_argument("--rate", type=positive_float, default=1.0, help="speed factor (2: twice as fast)")
    ros.add_argument("--loop", action="store_true", help="start again after the last message, until stopped")
    ros.add_argument("--start-offset", type=non_negative_float, default=0.0, metavar="S",
                     help="skip the first S seconds of the recording (latched topics still go out)")
    ros.add_argument("--clock", action="store_true", help="publish /clock with the recording's time at 40 Hz")
    ros.add_argument("--wait-for-subscribers", type=int, default=DEFAULT_WAIT_FOR_SUBSCRIBERS, metavar="N",
                     help="start once N subscribers listen, each matched on every replayed topic it subscribes to, "
                          f"and discovery has settled (default {DEFAULT_WAIT_FOR_SUBSCRIBERS}; 0: at once)")
    ros.add_argument("--wait-topic", metavar="TOPIC", default=None,
                     help="count only the subscribers of this replayed topic (default: of any replayed topic)")
    ros.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: the environment's)")
    view = parser.add_argument_group("Rerun instead of ROS")
    sink = view.add_mutually_exclusive_group()
    sink.add_argument("--rrd", type=writable_output, metavar="OUT.rrd", help="write a Rerun recording file")
    sink.add_argument("--connect", metavar="URL", type=connect_url, nargs="?",
                      const=f"rerun+http://127.0.0.1:{DEFAULT_VIEWER_PORT}/proxy",
                      help="stream to a running viewer or server: its gRPC URL or port "
                           f"(default rerun+http://127.0.0.1:{DEFAULT_VIEWER_PORT}/proxy)")
    sink.add_argument("--spawn", action="store_true", help="start a native viewer and stream to it")
    view.add_argument("--f0-hz", type=positive_float, default=None,
                      help="nominal frequency, Hz, to label a recording without run parameters "
                           "(refused when the recording has them: it says f0 itself)")
    about = parser.add_argument_group("Describe or draw (no ROS, no Rerun)")
    what = about.add_mutually_exclusive_group()
    what.add_argument("--info", action="store_true",
                      help="print what `ros2 bag info` shows, whether the file is complete, the run's parameters "
                           "and its verdicts")
    what.add_argument("--plot", type=writable_output, metavar="OUT.png", help="draw the run's figure")
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


def refuse_options(args, ros_args: list[str], defaults: dict, kind: str, use: str) -> None:
    """CliError naming every option of ``defaults`` set away from its default (and ``--ros-args``) for ``use``."""
    misplaced = ["--" + name.replace("_", "-") for name, default in defaults.items() if getattr(args, name) != default]
    if ros_args:
        misplaced.append("--ros-args")
    if misplaced:
        raise CliError(f"{', '.join(misplaced)}: {kind}, not for {use}")


def play(args, ros_args: list[str]) -> int:
    """ROS playback: read and plan first (bad input never starts ROS), then spin the node."""
    recording = load(args)
    playback = plan_playback(args.recording, list(recording.messages), args.start_offset)
    if args.wait_topic is not None and args.wait_topic not in playback.topics:
        raise CliError(f"--wait-topic {args.wait_topic}: not a topic of {args.recording} "
                       f"(it holds {', '.join(sorted(playback.topics))})")
    if args.clock and contract.TOPIC_CLOCK in playback.topics:
        raise CliError(f"{args.recording} already holds {contract.TOPIC_CLOCK} (a lockstep run): "
                       "replay it without --clock")
    if args.domain_id is not None:
        if not 0 <= args.domain_id <= 232:
            raise CliError(f"ROS domain id must be within 0..232, got {args.domain_id}")
        os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
    from nni_msgs_adapter.ros.node_main import run_node
    from nni_msgs_adapter.recording.replay_node import ReplayNode

    return run_node(lambda: ReplayNode(playback, rate=args.rate, loop=args.loop, clock=args.clock,
                                       wait_for_subscribers=args.wait_for_subscribers,
                                       wait_topic=args.wait_topic),
                    [PROG, *ros_args], prog=PROG)


def main(argv=None) -> int:
    """Entry point of ``nni-replay`` and ``ros2 run nni_msgs_adapter replay``."""
    own, ros_args = split_ros_args(sys.argv[1:] if argv is None else list(argv))
    parser = build_parser()

    def body() -> int:
        args = parser.parse_args(own)
        if args.wait_for_subscribers < 0:
            raise CliError(f"--wait-for-subscribers must be >= 0, got {args.wait_for_subscribers}")
        viewing = args.rrd is not None or args.connect is not None or args.spawn
        describing = args.info or args.plot is not None
        if viewing and describing:
            raise CliError("--info/--plot: not with --rrd/--connect/--spawn (one output at a time)")
        if viewing or describing:
            refuse_options(args, ros_args, _ROS_ONLY, "ROS playback options",
                           "--rrd/--connect/--spawn" if viewing else "--info/--plot")
        if describing:
            refuse_options(args, [], _RERUN_ONLY, "a Rerun option", "--info/--plot")
            return describe(args) if args.info else plot(args)
        if viewing:
            return convert(args)
        refuse_options(args, [], _RERUN_ONLY, "a Rerun option", "ROS playback")
        return play(args, ros_args)

    return run_cli(body, PROG)


if __name__ == "__main__":
    sys.exit(main())
