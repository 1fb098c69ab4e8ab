"""Read an NNI recording (MCAP) into per-generator sample arrays.

One generator is one namespace ('' for the root, ``/gen1``, ...): its
``plant/state`` samples, the ``controller/state`` signals aligned to them by
stamp, the invariant-set polygon and the plant's last diagnostics. Used by the
demo's summary, replay's Rerun conversion and the tests, so that a recording is
read one way everywhere.

No node and no ROS graph: messages are decoded with :func:`mcap_io.deserialize`
(rclpy's serializer, imported on first use), so this works without rclpy.init.

A recording also describes itself: the logger's ``run_metadata`` is the MCAP metadata record
``nni_run`` (each top-level key -> its JSON text), read back by :func:`run_metadata`. Recordings
made before it existed have none; what only needs the states reads them all the same.
"""

from __future__ import annotations

import heapq
import itertools
import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.recording.mcap_io import (
    RecordedMessage, Recording, RecordingError, deserialize, message_class, read_recording,
)

#: Name of the MCAP metadata record that holds the run's parameters (the logger's ``run_metadata``).
RUN_METADATA_NAME = "nni_run"

#: Contract topics published once per sample (pmu, command, states, /clock).
SAMPLE_TOPICS = (contract.TOPIC_PMU, contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_PLANT_STATE,
                 contract.TOPIC_CONTROLLER_STATE, contract.TOPIC_CLOCK)

# Longest contract name first, so that a name never matches a shorter suffix of itself.
_RELATIVE_TOPICS = sorted((name for name in contract.TOPICS if not name.startswith("/")), key=len, reverse=True)


#: The logger records a message on a sealed topic whose seal does not verify under the run's key on this prefix and
#: its topic (``/nni_foreign/gen1/pmu``): apart, so that no reader takes a rogue's sample for the loop's.
FOREIGN_PREFIX = "/nni_foreign"


class ClockTicks:
    """Which ``/clock`` ticks are the plant's, for a recorder holding the run's key.

    ``rosgraph_msgs/Clock`` has no room for a seal, but in lockstep the plant sends one tick per measurement, at the
    measurement's stamp, just after it. A tick is the loop's when a measurement of the same stamp was sealed by the
    plant (:meth:`measured`, fed with every ``pmu`` that verified) and no tick of that stamp was taken before (a
    tick holds nothing but its time: a rogue's copy of the next stamp is the same tick, once). It is foreign when it
    cannot be the loop's: its stamp is not ahead of every sealed measurement and none had it (each ``pmu`` topic
    arrives in order and carries every stamp), or no sealed measurement had it by the end (:meth:`rest`). Until
    then it waits (at most ``memory`` ticks: a flood of future ticks beyond that is foreign, farthest first).
    Each call returns the ticks it decided, ``[(item, is_loop)]``; ``item`` is what the caller keeps of the tick (a
    recorder writes it with its own receive time, so a tick that waited keeps its place in the log). ``memory``
    sealed stamps are remembered: a tick older than all of them is foreign (a rogue's replay). With ``plant_ticks``
    False (a realtime run: the plant sends no tick) every tick is foreign."""

    def __init__(self, memory: int = 4096, plant_ticks: bool = True):
        self._memory = memory
        self._plant_ticks = plant_ticks
        self._stamps: dict[int, bool] = {}  # sealed measurement stamp -> a tick of it was taken
        self._latest: int | None = None
        self._pending: list[tuple[int, int, object]] = []  # heap of (stamp, arrival, item)
        self._arrivals = 0

    def _decide(self, stamp_ns: int, item) -> tuple:
        loop = self._stamps.get(stamp_ns) is False
        if loop:
            self._stamps[stamp_ns] = True
        return item, loop

    def measured(self, stamp_ns: int) -> list:
        if stamp_ns not in self._stamps:
            self._stamps[stamp_ns] = False
            if len(self._stamps) > 2 * self._memory:  # forget the oldest half at once: amortised O(1)
                for old in list(itertools.islice(self._stamps, self._memory)):
                    del self._stamps[old]
        self._latest = stamp_ns if self._latest is None else max(self._latest, stamp_ns)
        decided = []
        while self._pending and self._pending[0][0] <= self._latest:
            stamp, _, item = heapq.heappop(self._pending)
            decided.append(self._decide(stamp, item))
        return decided

    def tick(self, stamp_ns: int, item) -> list:
        if not self._plant_ticks:
            return [(item, False)]
        if stamp_ns in self._stamps or (self._latest is not None and stamp_ns < self._latest):
            return [self._decide(stamp_ns, item)]
        self._arrivals += 1
        heapq.heappush(self._pending, (stamp_ns, self._arrivals, item))
        if len(self._pending) <= 2 * self._memory:
            return []
        ordered = sorted(self._pending, key=lambda entry: entry[:2])
        self._pending = ordered[:self._memory]  # sorted: a heap
        return [(item, False) for _, _, item in ordered[self._memory:]]

    def rest(self) -> list:
        """At the end: the ticks still waiting, every one foreign (no sealed measurement had its stamp)."""
        decided = [(item, False) for _, _, item in sorted(self._pending, key=lambda entry: entry[:2])]
        self._pending = []
        return decided


def foreign_counts(recording: Recording) -> dict[str, int]:
    """``{topic: messages}`` the logger recorded apart as not the loop's (:data:`FOREIGN_PREFIX`), by the topic they
    came on."""
    counts: dict[str, int] = {}
    for record in recording.messages:
        if record.topic.startswith(FOREIGN_PREFIX + "/"):
            topic = record.topic[len(FOREIGN_PREFIX):]
            counts[topic] = counts.get(topic, 0) + 1
    return counts


def split_topic(topic: str) -> tuple[str, str] | None:
    """``(namespace, contract topic)`` of a fully qualified name, or None if outside the contract.

    The one matcher of topic names (the logger records what it matches, readers read it):
    ``/gen1/plant/state`` -> ``("/gen1", "plant/state")``, ``/pmu`` -> ``("", "pmu")``;
    the contract's absolute names match only themselves: ``/clock`` -> ``("", "/clock")``,
    ``/diagnostics`` -> ``("", "/diagnostics")`` (whose statuses name their generator).
    """
    if topic in contract.TOPICS:
        return "", topic
    if topic.startswith(FOREIGN_PREFIX + "/"):
        return None  # where the logger puts what was not the loop's: no generator's
    for name in _RELATIVE_TOPICS:
        if topic.endswith("/" + name):
            return topic[: -len(name) - 1], name
    return None



def new_loop_topics(node, seen) -> list[tuple[str, str, list]]:
    """The contract topics on ``node``'s graph not in ``seen`` that have a publisher of the contract's type:
    ``(topic, contract name, the publishers' endpoint info)`` each (what the logger and the Foxglove bridge
    subscribe to as the graph grows)."""
    found = []
    for topic, types in node.get_topic_names_and_types():
        split = None if topic in seen else split_topic(topic)
        if split is None or contract.TOPICS[split[1]][0] not in types:
            continue
        publishers = node.get_publishers_info_by_topic(topic)
        if publishers:  # only subscribers so far: nothing to read yet (and no QoS for the logger to record)
            found.append((topic, split[1], publishers))
    return found

#: Logged (INFO) by a recorder (the MCAP logger, the Foxglove bridge) when its subscription to a topic has matched
#: every writer its graph knows on it: ``MATCHED_PREFIX + "/pmu <- /plant, /rogue"``. A launcher that must not
#: release the plant before the recorder hears the loop's writers waits for the line naming them
#: (:func:`nni_battery_controller.demo_common.wait_for_recorder`): a reader count cannot tell, since any process
#: on the domain that subscribes to ``/pmu`` (a rogue) counts as one of the plant's readers.
MATCHED_PREFIX = "matched the writers of "


class WriterMatches:
    """What a recorder logs as its subscriptions match the graph's writers (:data:`MATCHED_PREFIX` lines)."""

    def __init__(self):
        self._logged: dict[str, tuple[str, ...]] = {}

    def new_lines(self, node, subscriptions: dict) -> list[str]:
        """``topic <- writer, ...`` for each topic of ``subscriptions`` (``{topic: subscription or None}``) whose
        subscription has matched as many writers as ``node``'s graph lists there, when that list changed."""
        lines = []
        for topic, subscription in subscriptions.items():
            if subscription is None:
                continue
            infos = node.get_publishers_info_by_topic(topic)
            writers = tuple(sorted({"/".join(filter(None, (*info.node_namespace.split("/"), info.node_name)))
                                    for info in infos}))
            if infos and subscription.get_publisher_count() >= len(infos) and self._logged.get(topic) != writers:
                self._logged[topic] = writers
                lines.append(f"{MATCHED_PREFIX}{topic} <- {', '.join('/' + w for w in writers)}")
        return lines


def run_metadata(recording: Recording) -> dict | None:
    """The run's parameters (the ``nni_run`` record, values decoded from JSON), or None if not recorded.

    Raises
    ------
    RecordingError
        If a value of the record is not JSON.
    """
    record = recording.metadata.get(RUN_METADATA_NAME)
    if record is None:
        return None
    try:
        return {key: json.loads(text) for key, text in record.items()}
    except json.JSONDecodeError as error:
        raise RecordingError(f"{recording.path}: metadata {RUN_METADATA_NAME!r} holds a value that is not JSON: "
                             f"{error}") from None


@dataclass(frozen=True)
class GeneratorRun:
    """One generator's run as recorded. Sample arrays share shape ``(n,)``, ordered by stamp.

    Attributes
    ----------
    namespace : str
        ``""`` (root namespace) or e.g. ``"/gen1"``.
    stamp_ns : numpy.ndarray of int64
        ``plant/state`` header stamps, ns (simulated time in lockstep, epoch time in realtime).
    delta_rad : numpy.ndarray
        Rotor angle delta, rad.
    speed_rad_s : numpy.ndarray
        Speed deviation delta' = omega - omega0, rad/s.
    battery_power_pu : numpy.ndarray
        Battery power P_ST acting on the rotor from this sample on, pu.
    signals : dict of str to numpy.ndarray
        ``controller/state`` signals (``contract.CONTROLLER_SIGNALS``) at the same stamps; NaN
        where the controller did not report (the final state of a run answers no sample).
    omega_boundary : numpy.ndarray or None
        Boundary of the invariant set Omega, ``(m, 2)`` points (angle deviation rad, speed rad/s),
        from the last ``plant/invariant_set``; None if not recorded.
    diagnostics : dict of str to str
        Key/values of the plant's last ``diagnostics`` status (empty if none was recorded).
    skipped : tuple of str
        One line per sample left out because its message broke the contract (a non-finite
        true state, for example): reported, the rest of the run still read.
    controller_diagnostics : dict of str to str
        Key/values of the controller's last ``diagnostics`` status (empty if none was recorded).
    """

    namespace: str
    stamp_ns: np.ndarray
    delta_rad: np.ndarray
    speed_rad_s: np.ndarray
    battery_power_pu: np.ndarray
    signals: dict = field(default_factory=dict)
    omega_boundary: np.ndarray | None = None
    diagnostics: dict = field(default_factory=dict)
    skipped: tuple = ()
    controller_diagnostics: dict = field(default_factory=dict)

    @property
    def t_s(self) -> np.ndarray:
        """Time since the first sample, s."""
        return (self.stamp_ns - self.stamp_ns[0]) * 1e-9

    @property
    def answered(self) -> np.ndarray:
        """Samples the controller answered (has a ``controller/state`` at their stamp)."""
        return ~np.isnan(self.signals["angle_dev"])

    @property
    def saturated(self) -> np.ndarray:
        """Saturation flag per sample (False where the controller did not report)."""
        return self.signals["saturated"] > 0.5

    @property
    def battery_limit_pu(self) -> float:
        """The controller's battery limit b (pu, may be inf); NaN if the controller never reported."""
        limits = self.signals["battery_limit"]
        known = limits[~np.isnan(limits)]
        return float(known[0]) if known.size else math.nan


@dataclass
class _Collected:
    states: list = field(default_factory=list)
    signals: dict = field(default_factory=dict)
    omega_boundary: np.ndarray | None = None
    diagnostics: dict = field(default_factory=dict)
    skipped: list = field(default_factory=list)
    controller_diagnostics: dict = field(default_factory=dict)


def read_generator_runs(path: str | os.PathLike[str]) -> dict[str, GeneratorRun]:
    """Every generator of a recording, by namespace.

    Parameters
    ----------
    path : str or os.PathLike
        An MCAP recording, finished or cut short (see :func:`mcap_io.read_messages`).

    Returns
    -------
    dict of str to GeneratorRun
        One entry per namespace that has ``plant/state`` messages, in namespace order.

    Raises
    ------
    RecordingError
        If the file cannot be read, a channel's message type is unknown or is not the one the
        contract gives its topic, a contract message is malformed, or no namespace has
        ``plant/state``.
    """
    return generator_runs(read_recording(path))


def generator_runs(recording: Recording) -> dict[str, GeneratorRun]:
    """Every generator of a recording already read (:func:`mcap_io.read_recording`); as :func:`read_generator_runs`."""
    path = recording.path
    collected: dict[str, _Collected] = {}
    checked_topics: set[str] = set()
    for record in recording.messages:
        if record.topic not in checked_topics:
            check_message_type(path, record)
            checked_topics.add(record.topic)
        split = split_topic(record.topic)
        if split is None or split[1] == contract.TOPIC_CLOCK:
            continue
        namespace, name = split
        try:
            msg = deserialize(record.type_name, record.cdr_bytes)
            if name == contract.TOPIC_DIAGNOSTICS:
                _collect_diagnostics(collected, msg)
            else:
                _collect(collected.setdefault(namespace, _Collected()), name, msg)
        except contract.ContractError as error:
            if name not in SAMPLE_TOPICS:
                raise RecordingError(f"{path}: malformed message on {record.topic}: {error}") from None
            collected.setdefault(namespace, _Collected()).skipped.append(
                f"{record.topic} at log time {record.log_time_ns} ns: {error}")
        except RecordingError as error:
            raise RecordingError(f"{path}: malformed message on {record.topic}: {error}") from None
    runs = {ns: _generator_run(ns, run) for ns, run in sorted(collected.items()) if run.states}
    check_has_plant_state(path, [ns + "/" + contract.TOPIC_PLANT_STATE for ns in runs])
    return runs


def read_generator_run(path: str | os.PathLike[str], namespace: str | None = None) -> GeneratorRun:
    """The run of one generator: the one in ``namespace``, or the only one if None.

    Raises
    ------
    RecordingError
        As :func:`read_generator_runs`; also if ``namespace`` is None and the recording holds
        several generators, or ``namespace`` holds none.
    """
    runs = read_generator_runs(path)
    if namespace is None:
        if len(runs) > 1:
            raise RecordingError(f"{path}: holds generators in {', '.join(runs)}; choose one namespace")
        return next(iter(runs.values()))
    if namespace not in runs:
        raise RecordingError(f"{path}: no {contract.TOPIC_PLANT_STATE} in namespace {namespace!r}")
    return runs[namespace]


def check_message_type(path: str | os.PathLike[str], record: RecordedMessage) -> None:
    """Raise RecordingError unless the record's type is installed and, on a contract topic, the contract's."""
    try:
        message_class(record.type_name)
    except RecordingError as error:
        raise RecordingError(f"{path}: topic {record.topic}: {error}") from None
    split = split_topic(record.topic)
    if split is not None:
        expected = contract.TOPICS[split[1]][0]
        if record.type_name != expected:
            raise RecordingError(f"{path}: topic {record.topic} carries {record.type_name}, "
                                 f"the contract gives it {expected}")


def check_has_plant_state(path: str | os.PathLike[str], topics) -> None:
    """Raise RecordingError unless one of ``topics`` is a ``plant/state`` (in any namespace)."""
    if not any((split_topic(topic) or ("", ""))[1] == contract.TOPIC_PLANT_STATE for topic in topics):
        raise RecordingError(f"{path}: no {contract.TOPIC_PLANT_STATE} messages in any namespace: "
                             "not a recording of a plant run")


def _collect(run: _Collected, name: str, msg) -> None:
    if name == contract.TOPIC_PLANT_STATE:
        run.states.append(contract.plant_state_from_message(msg))
    elif name == contract.TOPIC_CONTROLLER_STATE:
        stamp_ns, values = contract.controller_state_from_message(msg)
        run.signals[stamp_ns] = values
    elif name == contract.TOPIC_INVARIANT_SET:
        run.omega_boundary = np.array([(p.x, p.y) for p in msg.polygon.points], dtype=np.float64).reshape(-1, 2)


def _collect_diagnostics(collected: dict, msg) -> None:
    """The plant's and the controller's statuses of a ``/diagnostics`` message, each to the generator its name gives."""
    for status in msg.status:
        namespace, name = contract.split_status_name(status.name)
        if name == "plant":
            collected.setdefault(namespace, _Collected()).diagnostics = {kv.key: kv.value for kv in status.values}
        elif name == "controller":
            collected.setdefault(namespace, _Collected()).controller_diagnostics = {kv.key: kv.value
                                                                                   for kv in status.values}


def _generator_run(namespace: str, run: _Collected) -> GeneratorRun:
    states = sorted(run.states)
    stamps = np.array([s[0] for s in states], dtype=np.int64)
    values = np.array([s[1:] for s in states], dtype=np.float64)
    signals = {name: np.array([run.signals.get(stamp, {}).get(name, math.nan) for stamp in stamps.tolist()])
               for name in contract.CONTROLLER_SIGNALS}
    boundary = run.omega_boundary if run.omega_boundary is not None and len(run.omega_boundary) >= 2 else None
    return GeneratorRun(namespace, stamps, values[:, 0], values[:, 1], values[:, 2], signals, boundary,
                        run.diagnostics, tuple(run.skipped), run.controller_diagnostics)
