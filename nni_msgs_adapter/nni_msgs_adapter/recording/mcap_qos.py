"""The ``offered_qos_profiles`` channel metadata of a ROS 2 MCAP: write it as rosbag2 does, parse any.

Hand-written on purpose: rosbag2 (Jazzy, metadata version 9) writes this YAML with yaml-cpp, and
:func:`qos_profiles_yaml` reproduces that text byte for byte (rosbags' ``dump_qos_v9`` gives the
same maps, but its YAML dumper formats them differently). :func:`parse_qos_profiles_yaml` reads
what any rosbag2 wrote and, unlike rosbags' ``parse_qos`` (which maps an unknown policy to
UNKNOWN), refuses a malformed entry with its reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

import yaml

from nni_msgs_adapter.recording.mcap_profile import RecordingError

QOS_METADATA_KEY = "offered_qos_profiles"

# rmw_qos_*_policy_to_str (rmw, Jazzy), with rosbag2's "unknown" for the UNKNOWN values. The
# integers are the rmw enum values, which are also rclpy's QoS*Policy values.
_POLICY_NAMES: dict[str, dict[int, str]] = {
    "history": {0: "system_default", 1: "keep_last", 2: "keep_all", 3: "unknown"},
    "reliability": {
        0: "system_default", 1: "reliable", 2: "best_effort", 3: "unknown", 4: "best_available",
    },
    "durability": {
        0: "system_default", 1: "transient_local", 2: "volatile", 3: "unknown",
        4: "best_available",
    },
    "liveliness": {
        0: "system_default", 1: "automatic", 3: "manual_by_topic", 4: "unknown",
        5: "best_available",
    },
}  # fmt: skip
_POLICY_VALUES = {
    policy: {name: value for value, name in names.items()}
    for policy, names in _POLICY_NAMES.items()
}
_NS_PER_S = 1_000_000_000
# rmw's RMW_DURATION_INFINITE (what the graph reports for "no deadline"), ns.
_RMW_DURATION_INFINITE_NS = 2**63 - 1


@dataclass(frozen=True)
class OfferedQos:
    """One offered QoS profile as rosbag2 records it; durations in nanoseconds.

    Policies are the rmw enum integers (equal to rclpy's ``QoS*Policy`` values); a zero
    duration means the rmw default (unspecified).

    Attributes
    ----------
    history, depth, reliability, durability, liveliness : int
        QoS policies (``depth`` counts messages).
    deadline_ns, lifespan_ns, liveliness_lease_duration_ns : int
        Durations in nanoseconds.
    avoid_ros_namespace_conventions : bool
        The rmw flag of the same name.
    """

    history: int = 1
    depth: int = 10
    reliability: int = 1
    durability: int = 2
    deadline_ns: int = 0
    lifespan_ns: int = 0
    liveliness: int = 0
    liveliness_lease_duration_ns: int = 0
    avoid_ros_namespace_conventions: bool = False

    @classmethod
    def from_rclpy(cls, profile: Any) -> OfferedQos:
        """Copy an ``rclpy.qos.QoSProfile`` (policies as integers, durations in nanoseconds)."""
        return cls(
            history=int(profile.history),
            depth=int(profile.depth),
            reliability=int(profile.reliability),
            durability=int(profile.durability),
            deadline_ns=profile.deadline.nanoseconds,
            lifespan_ns=profile.lifespan.nanoseconds,
            liveliness=int(profile.liveliness),
            liveliness_lease_duration_ns=profile.liveliness_lease_duration.nanoseconds,
            avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
        )

    def to_rclpy(self) -> Any:
        """The equivalent ``rclpy.qos.QoSProfile`` (imports rclpy)."""
        from rclpy.duration import Duration
        from rclpy.qos import (
            DurabilityPolicy,
            HistoryPolicy,
            LivelinessPolicy,
            QoSProfile,
            ReliabilityPolicy,
        )

        return QoSProfile(
            history=HistoryPolicy(self.history),
            depth=self.depth,
            reliability=ReliabilityPolicy(self.reliability),
            durability=DurabilityPolicy(self.durability),
            deadline=Duration(nanoseconds=self.deadline_ns),
            lifespan=Duration(nanoseconds=self.lifespan_ns),
            liveliness=LivelinessPolicy(self.liveliness),
            liveliness_lease_duration=Duration(nanoseconds=self.liveliness_lease_duration_ns),
            avoid_ros_namespace_conventions=self.avoid_ros_namespace_conventions,
        )


def _policy_name(policy: str, value: int) -> str:
    try:
        return _POLICY_NAMES[policy][value]
    except KeyError:
        raise ValueError(f"{value} is not an rmw {policy} policy") from None


def _duration_yaml(key: str, nanoseconds: int) -> list[str]:
    seconds, remainder = divmod(nanoseconds, _NS_PER_S)
    return [f"  {key}:", f"    sec: {seconds}", f"    nsec: {remainder}"]


def qos_profiles_yaml(profiles: Iterable[Any]) -> str:
    """The ``offered_qos_profiles`` channel metadata, byte for byte as rosbag2 (Jazzy) writes it.

    rosbag2 0.26 serializes with yaml-cpp (``rosbag2_storage::serialize_rclcpp_qos_vector``,
    metadata version 9): a block list of maps with keys in the order below, policies as rmw
    names, durations as ``sec``/``nsec`` maps, no trailing newline::

        - history: keep_last
          depth: 10
          reliability: reliable
          durability: volatile
          deadline:
            sec: 0
            nsec: 0
          lifespan:
            sec: 0
            nsec: 0
          liveliness: system_default
          liveliness_lease_duration:
            sec: 0
            nsec: 0
          avoid_ros_namespace_conventions: false

    Parameters
    ----------
    profiles : iterable of rclpy.qos.QoSProfile or OfferedQos
        The profiles offered by the topic's publishers.

    Returns
    -------
    str
        The YAML text; ``"[]"`` for no profiles (yaml-cpp's empty sequence).
    """
    lines: list[str] = []
    for profile in profiles:
        qos = profile if isinstance(profile, OfferedQos) else OfferedQos.from_rclpy(profile)
        lines += [
            f"- history: {_policy_name('history', qos.history)}",
            f"  depth: {qos.depth}",
            f"  reliability: {_policy_name('reliability', qos.reliability)}",
            f"  durability: {_policy_name('durability', qos.durability)}",
            *_duration_yaml("deadline", qos.deadline_ns),
            *_duration_yaml("lifespan", qos.lifespan_ns),
            f"  liveliness: {_policy_name('liveliness', qos.liveliness)}",
            *_duration_yaml("liveliness_lease_duration", qos.liveliness_lease_duration_ns),
            f"  avoid_ros_namespace_conventions: {str(qos.avoid_ros_namespace_conventions).lower()}",
        ]
    return "\n".join(lines) if lines else "[]"


def describe_qos(profile: OfferedQos) -> str:
    """One profile as words, the policies that decide matching first: ``reliable, volatile, keep_last 100``."""
    words = [_policy_name("reliability", profile.reliability), _policy_name("durability", profile.durability)]
    if _policy_name("history", profile.history) != "unknown":  # the graph does not show a publisher's history
        words.append(f"{_policy_name('history', profile.history)} {profile.depth}")
    if 0 < profile.deadline_ns < _RMW_DURATION_INFINITE_NS:
        words.append(f"deadline {profile.deadline_ns * 1e-9:g} s")
    if profile.liveliness:
        words.append(f"liveliness {_policy_name('liveliness', profile.liveliness)}")
    return ", ".join(words)


def _parse_policy(policy: str, value: Any) -> int:
    """A policy from its rmw name (metadata v9) or its integer (metadata v8 and older)."""
    if isinstance(value, int) and not isinstance(value, bool):
        if value in _POLICY_NAMES[policy]:
            return value
    elif isinstance(value, str) and value in _POLICY_VALUES[policy]:
        return _POLICY_VALUES[policy][value]
    raise RecordingError(f"offered_qos_profiles: {value!r} is not a {policy} policy")


def _parse_duration(key: str, value: Any) -> int:
    if not isinstance(value, dict) or not {"sec", "nsec"} <= value.keys():
        raise RecordingError(f"offered_qos_profiles: {key} is not a map with sec and nsec")
    return int(value["sec"]) * _NS_PER_S + int(value["nsec"])


def parse_qos_profiles_yaml(text: str) -> list[OfferedQos]:
    """Parse ``offered_qos_profiles`` metadata back into profiles.

    Accepts what rosbag2 of any distribution wrote: policies as names (Jazzy, metadata
    version 9) or as integers (Humble and older); an empty string means no profiles.

    Parameters
    ----------
    text : str
        The channel metadata value.

    Returns
    -------
    list of OfferedQos
        One entry per recorded publisher profile.

    Raises
    ------
    RecordingError
        If the text is not a YAML list of complete QoS maps.
    """
    try:
        entries = yaml.safe_load(text) if text.strip() else []
    except yaml.YAMLError as error:
        reason = str(error).splitlines()[0]
        raise RecordingError(f"offered_qos_profiles is not YAML: {reason}") from None
    if not isinstance(entries, list):
        raise RecordingError("offered_qos_profiles is not a YAML list")
    profiles = []
    for entry in entries:
        if not isinstance(entry, dict):
            raise RecordingError("offered_qos_profiles: an entry is not a map")
        try:
            profiles.append(
                OfferedQos(
                    history=_parse_policy("history", entry["history"]),
                    depth=int(entry["depth"]),
                    reliability=_parse_policy("reliability", entry["reliability"]),
                    durability=_parse_policy("durability", entry["durability"]),
                    deadline_ns=_parse_duration("deadline", entry["deadline"]),
                    lifespan_ns=_parse_duration("lifespan", entry["lifespan"]),
                    liveliness=_parse_policy("liveliness", entry["liveliness"]),
                    liveliness_lease_duration_ns=_parse_duration(
                        "liveliness_lease_duration", entry["liveliness_lease_duration"]
                    ),
                    avoid_ros_namespace_conventions=bool(
                        entry["avoid_ros_namespace_conventions"]
                    ),
                )
            )
        except KeyError as missing:
            raise RecordingError(f"offered_qos_profiles: an entry has no {missing}") from None
    return profiles
