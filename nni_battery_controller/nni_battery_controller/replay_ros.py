"""ROS playback, what ``nni-replay`` does by default: planned from the file first, then published by :mod:`replay_node`.

::

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

The plan (:func:`plan_playback`) is worked out before any ROS call, so that bad input
never starts ROS; :func:`play` then hands it to :class:`replay_node.ReplayNode`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.cli_support import CliError
from nni_msgs_adapter.recording.mcap_io import OfferedQos, RecordedMessage, parse_qos_profiles_yaml
from nni_battery_controller.replay_load import PROG, load
from nni_msgs_adapter.recording.runs import check_has_plant_state, check_message_type, split_topic

#: Subscribers a playback waits for by default: someone must listen (see the module docstring).
DEFAULT_WAIT_FOR_SUBSCRIBERS = 1

#: rmw durability policy value (also rclpy's) of latched topics.
_TRANSIENT_LOCAL = 1


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
