"""The plant's reporting loop and command path, without ROS: times (ns) and commands in, what to publish out.

The plant node only translates: it hands in the wall time of each timer tick,
each battery command (with the writers it can see on the command topic) and
each handshake event, and publishes what comes back. Everything it used to
decide itself lives here, clock-free and unit-tested:

* :class:`CommandChannel`, one generator's battery: whose commands it takes
  (those that verify under the run's key, or those of the one writer it is
  paired with), which measurements it sent and which are answered, the rating
  (commands beyond it are clipped), and why any other command is dropped
  (:class:`Verdict`, counted per reason).
* :class:`RealtimeReporter`: the PMU reporting grid t0 + k T (T the timer's
  period in whole ns), integrate-ahead and redo, skipped reports, the command
  timeout.
* :class:`LockstepStepper`: the handshake, one period per answered sample or
  per timeout.

Both loops drive any plant given as ``integrate(t0_s, t1_s, state, powers) ->
state`` (``powers``: a sequence, one battery power in pu per generator, in the
order of ``channels``) and serve one :class:`CommandChannel` per generator
behind one reporting grid, so a plant of N generators reuses them unchanged.

Both take a :class:`nni_plant_sim.link.Link` (default: none): an admitted
answer to measurement k takes effect at t_k + d_k (lockstep: simulated time;
realtime: the reporting grid's clock, or at its arrival if that is later), or
is lost and the command in force stays; the physics is integrated piecewise
between those instants (:class:`nni_plant_sim.link.DelayLine`), as the
offline sampled simulations do. Without a link every answer takes effect at
once and each period is one piece, as before the model existed. Both also
take a :class:`nni_plant_sim.battery.EnergyStore` (default: none, no energy
limit): the line cuts a piece where a battery runs empty or full, the physics
gets the powers the batteries give, and each :class:`Report` carries them
(the charge: :attr:`_Loop.store`).
"""

from __future__ import annotations

import enum
import math
from typing import NamedTuple

import numpy as np

from nni_msgs_adapter.ros import command_auth
from nni_plant_sim.battery import EnergyStore
from nni_plant_sim.link import NO_LINK, DelayLine, Link, integrate_through
from nni_plant_sim.loop_stats import LoopStats, TimingDistribution

#: A battery command beyond this is a fault, not a request to clip (a battery a
#: thousand times the machine's base power does not exist): dropped as invalid.
MAX_PLAUSIBLE_POWER_PU = 1e3

#: Counters of the command path, always present in the plant's diagnostics and summary (INTERFACES.md item 1).
TRUST_KEYS = ("unauthenticated_commands", "replayed_commands", "foreign_commands", "unsolicited_commands",
              "expired_commands", "invalid_commands", "clipped_commands", "writer_alarms")
#: The counters of which any non-zero one means someone else than the controller wrote on the command topic.
COMPROMISING_KEYS = ("unauthenticated_commands", "replayed_commands", "foreign_commands", "unsolicited_commands",
                     "writer_alarms")


class Verdict(enum.Enum):
    """What became of one battery command; the dropped ones name their counter."""

    APPLIED = "applied"
    STAND_DOWN = "stand_down_commands"      # the controller's zero on stale data: the safe state
    UNAUTHENTICATED = "unauthenticated_commands"  # no seal, or one that does not verify under the run's key
    REPLAYED = "replayed_commands"          # a seal that verifies, on a sequence number already used
    FOREIGN = "foreign_commands"            # (writer pairing) another writer is on the topic: nothing can be trusted
    UNSOLICITED = "unsolicited_commands"    # answers no measurement the plant sent, or one already answered
    EXPIRED = "expired_commands"            # answers a measurement older than its deadline
    INVALID = "invalid_commands"            # non-finite or implausible power


def ns_from_seconds(t_s: float) -> int:
    """Nanoseconds nearest to ``t_s`` seconds (simulated time stamps)."""
    return int(round(t_s * 1e9))


class CommandChannel:
    """One generator's battery command path: whose commands count, answers, limits and the power in force.

    ``deadline_ns``: an answer arriving later than this after its measurement's
    instant is expired (realtime; lockstep passes the awaited stamp instead).

    ``verifier`` (a :class:`nni_msgs_adapter.ros.command_auth.CommandVerifier`,
    the plant's ``command_authentication hmac``): a command counts only if its
    seal verifies under the run's key, on a sequence number above the last one
    that did; anything else is dropped (``unauthenticated_commands``,
    ``replayed_commands``) while the controller's commands keep being applied.
    A second writer on the topic is still an alarm (``writer_alarms``): the
    run is flagged, but nothing is blocked.

    Without a verifier (``command_authentication none``, writer pairing): rclpy
    (Jazzy) gives a subscription callback no publisher GID, so a command cannot
    be attributed to its writer. The channel is paired with the one writer on
    the topic (its GID and node name, from the ROS graph); while any other
    writer is matched, every command is dropped as foreign (nothing can be
    trusted, the battery falls back to zero at the timeout). When the paired
    writer has left the graph and exactly one writer remains (a restarted
    controller), the channel pairs with it, counted in ``re_pairings``.
    Either way each new writer beyond the first raises an alarm.
    """

    def __init__(self, rating_pu: float, deadline_ns: int, verifier=None):
        self.stats = LoopStats()
        self.rating_pu = rating_pu
        self.deadline_ns = deadline_ns
        self.verifier = verifier
        self.power_pu = 0.0
        self.max_abs_applied_power_pu = 0.0
        self.paired: tuple[bytes, str] | None = None
        self.foreign: dict[bytes, str] = {}
        self.counts = dict.fromkeys((*TRUST_KEYS, "stand_down_commands", "re_pairings"), 0)
        self.alarm = ""  # the latest alarm's text
        self._events: list[tuple[bool, str]] = []

    def take_events(self) -> list[tuple[bool, str]]:
        """``(alarm, text)`` of what happened since the last call: pairings, new writers, first drops of a kind."""
        events, self._events = self._events, []
        return events

    def _event(self, alarm: bool, text: str) -> None:
        if alarm:
            self.alarm = text
        self._events.append((alarm, text))

    def writers(self, writers: dict[bytes, str], unlisted: int = 0) -> None:
        """The writers now on the command topic (``{gid: node name}``), and how many more are matched but unlisted.

        An unlisted writer (matched, not yet in the ROS graph) blocks like any other but is never paired.
        """
        paired_gid = None if self.paired is None else self.paired[0]
        if paired_gid not in writers and len(writers) == 1 and not unlisted:
            (gid, name), = writers.items()
            if self.paired is not None:
                self.counts["re_pairings"] += 1
            self._event(False, f"paired with the controller {name} ({gid.hex()}) on battery/command")
            self.paired, self.foreign = (gid, name), {}
            return
        if paired_gid in writers and writers[paired_gid] != self.paired[1]:  # the graph named it since
            self.paired = (paired_gid, writers[paired_gid])
        others = {gid: name for gid, name in writers.items() if gid != paired_gid}
        others.update({f"unlisted {n}".encode(): "(a writer not yet in the ROS graph)" for n in range(unlisted)})
        for gid, name in others.items():
            if gid not in self.foreign:
                self.counts["writer_alarms"] += 1
            if self.foreign.get(gid) != name:  # new, or named now
                self._event(True, f"foreign writer {name} ({gid.hex()}) on battery/command: " + (
                    "the run is flagged; only authenticated commands are applied" if self.verifier is not None
                    else "commands dropped"))
        self.foreign = others

    def admit(self, stamp_ns: int, power_pu: float, arrival_ns: int, awaited_ns: int | None = None,
              seal: bytes | None = None, sealed_stamp_ns: int | None = None) -> tuple[Verdict, float | None]:
        """Decide on a command answering ``stamp_ns``: the verdict and the power to put in force (None: nothing).

        ``seal``: the command's authentication (checked first, with a verifier), over the stamp the command
        carried, ``sealed_stamp_ns`` where that is not ``stamp_ns`` (a C37.118 stamp mapped back to the sample's).
        ``awaited_ns``: lockstep, the one stamp whose answer is due; None
        (realtime): any unanswered measurement within the deadline. A stand-down
        (the controller's zero on stale data, answering no measurement)
        is zero in realtime; lockstep waits for the sample's own answer.
        """
        if self.verifier is not None:
            check = self.verifier.check(seal, stamp_ns if sealed_stamp_ns is None else sealed_stamp_ns, power_pu)
            if check != command_auth.AUTHENTIC:
                return self._drop(Verdict.REPLAYED if check == command_auth.REPLAYED else Verdict.UNAUTHENTICATED,
                                  stamp_ns, power_pu)
        if not math.isfinite(power_pu) or abs(power_pu) > MAX_PLAUSIBLE_POWER_PU:
            return self._drop(Verdict.INVALID)
        if self.verifier is None and (self.foreign or self.paired is None):
            return self._drop(Verdict.FOREIGN, stamp_ns, power_pu)
        if self.stats.sent_wall_ns(stamp_ns) is None:
            if power_pu != 0.0:
                return self._drop(Verdict.UNSOLICITED, stamp_ns, power_pu)
            self.counts["stand_down_commands"] += 1
            return Verdict.STAND_DOWN, (0.0 if awaited_ns is None else None)
        if self.stats.is_answered(stamp_ns):
            self.stats.duplicates += 1  # of the unsolicited: answers to a measurement answered or superseded
            return self._drop(Verdict.UNSOLICITED, stamp_ns, power_pu)
        too_late = stamp_ns != awaited_ns if awaited_ns is not None else arrival_ns - stamp_ns > self.deadline_ns
        if too_late:
            return self._drop(Verdict.EXPIRED)
        self.stats.answered(stamp_ns, arrival_ns)
        clipped = min(max(power_pu, -self.rating_pu), self.rating_pu)
        if clipped != power_pu:
            self.counts["clipped_commands"] += 1
        return Verdict.APPLIED, clipped

    def apply(self, power_pu: float) -> None:
        """Put ``power_pu`` in force (admitted, or zero at a timeout)."""
        self.power_pu = power_pu
        self.max_abs_applied_power_pu = max(self.max_abs_applied_power_pu, abs(power_pu))

    def _drop(self, verdict: Verdict, stamp_ns: int = 0, power_pu: float = 0.0) -> tuple[Verdict, None]:
        """Count a dropped command; the first one of a compromising kind is an alarm (later ones: the counters)."""
        self.counts[verdict.value] += 1
        if verdict.value in COMPROMISING_KEYS and self.counts[verdict.value] == 1:
            self._event(True, f"{verdict.name.lower()} command dropped (stamp {stamp_ns} ns, {power_pu!r} pu)")
        return verdict, None

    @property
    def compromised(self) -> bool:
        """A command from someone else than the controller, or a second writer, was seen."""
        return any(self.counts[key] for key in COMPROMISING_KEYS)

    def health(self, started: bool, waiting_for: str) -> tuple[str, str]:
        """``(level, message)`` of the plant's status: level a DiagnosticStatus constant's name."""
        if self.compromised:  # before the run too: a rogue on the command topic is an alarm whenever it writes
            return "ERROR", f"compromised: {self.alarm}"
        return ("OK", "running") if started else ("WARN", waiting_for or "waiting for subscribers")

    def summary(self) -> dict:
        """Counters, timing and the largest applied power, for diagnostics."""
        return {**self.stats.summary(), **self.counts, "max_abs_applied_power_pu": self.max_abs_applied_power_pu,
                "paired_controller": "" if self.paired is None else self.paired[1],
                "command_authentication": "none" if self.verifier is None else command_auth.SCHEME}


class Report(NamedTuple):
    """An instant: the true state at it and the powers in force.

    NamedTuples, not dataclasses: two or three are made per lockstep sample, on its critical path
    (measured: 0.46 us to build against 1.1 us for a frozen dataclass).
    """

    stamp_ns: int
    t_s: float
    state: object
    powers: tuple


class Output(NamedTuple):
    """What to publish, in order: a measurement (lockstep: then /clock), then true states; ``done``: the run ended.

    The run's final instant has its state but no measurement nobody could answer.
    """

    measurement: Report | None
    states: tuple[Report, ...]
    done: bool


class _Loop:
    """The physics and the channels shared by both time modes."""

    def __init__(self, integrate, state, channels, duration_s: float, link: Link, store: EnergyStore | None = None):
        self._integrate = integrate
        self.state = state
        self.t_s = 0.0
        self.channels = list(channels)
        self.duration_s = duration_s
        self.sample = 0
        self.done = False
        self.link = link
        self.line = DelayLine(link, self.powers, lambda index, power: self.channels[index].apply(power), store)

    @property
    def powers(self) -> tuple:
        return tuple(channel.power_pu for channel in self.channels)

    def advance_to(self, t_s: float) -> None:
        if t_s > self.t_s:
            self.state = integrate_through(self.line, self._integrate, self.t_s, t_s, self.state)
            self.t_s = t_s

    def replace_state(self, state) -> None:
        """A fault moved the state (at the current time)."""
        self.state = state

    def link_summary(self, index: int) -> dict:
        """Channel ``index``'s answers the link lost and those superseded; nothing without a link."""
        if not self.link.active:
            return {}
        return {"link_lost": self.line.lost[index], "link_superseded": self.line.superseded[index]}

    @property
    def store(self) -> EnergyStore | None:
        """The batteries' charge, None without an energy limit."""
        return self.line.store

    def report(self, stamp_ns: int) -> Report:
        """The instant, with the powers as the batteries give them (an empty one gives none)."""
        if self.line.store is None:
            return Report(stamp_ns, self.t_s, self.state, self.powers)
        return Report(stamp_ns, self.t_s, self.state, tuple(self.line.applied_powers()))


class RealtimeReporter(_Loop):
    """Realtime: the reporting grid ``t0_ns + k period_ns``, commands in force from their arrival.

    As a PMU does (IEEE C37.118), the measurement of instant k is of the state
    at that instant and stamped with it. The state there is integrated while
    the loop is idle (once every channel has answered, up to the next instant;
    redone from a later arrival if another command comes first), so that a tick only
    publishes. A tick that fell more than a period behind reports the latest
    instant and counts the ones it skipped. A run of ``duration_s`` ends at its
    last instant N T, however late the tick that finds it. A command older
    than ``command_timeout_s`` decays to zero power.

    With a link, the answer to instant k is held until t_k + d_k on the
    reporting grid (at once if it arrived later than that); a lost answer
    counts as never heard, so that losses in a row for ``command_timeout_s``
    decay the power to zero as silence does. The controller's stand-down zero
    and a timeout's zero take effect at once and supersede older answers on
    their way.
    """

    def __init__(self, integrate, state, channels, duration_s: float, t0_ns: int, period_ns: int,
                 command_timeout_s: float, link: Link = NO_LINK, store: EnergyStore | None = None):
        super().__init__(integrate, state, channels, duration_s, link, store)
        self.t0_ns = t0_ns
        self.period_ns = period_ns
        self.period_s = period_ns * 1e-9
        self.command_timeout_s = command_timeout_s
        self._last = round(duration_s / self.period_s) if duration_s > 0 else None
        self._ahead = None  # (t_s, state, delay line) before integrating ahead to the next instant
        self._heard_ns: list[int | None] = [None] * len(self.channels)  # arrival of the last answer not lost

    def advance_to(self, t_s: float) -> None:
        if t_s < self.t_s and self._ahead is not None:
            # Integrated ahead past t_s with the powers then in force; something happens earlier: redo.
            self.t_s, self.state, line = self._ahead
            self.line.restore(line)
            self._ahead = None
        super().advance_to(t_s)

    def replace_state(self, state) -> None:
        super().replace_state(state)
        self._ahead = None  # a state integrated ahead is of the old trajectory

    def _elapsed_s(self, now_ns: int) -> float:
        return (now_ns - self.t0_ns) * 1e-9

    def due(self, now_ns: int, by_timer: bool = False) -> Output | None:
        """The latest reporting instant at or before ``now_ns``, unless it is reported already.

        ``by_timer``: the reporting timer fired for it (its lateness is jitter);
        False when a command or a service call found the instant passed first.
        """
        if self.done:
            return None
        instant = (now_ns - self.t0_ns) // self.period_ns
        if self._last is not None:
            instant = min(instant, self._last)
        if instant < self.sample:
            return None
        self.sample, skipped = instant, instant - self.sample
        self.advance_to(instant * self.period_s)
        self._ahead = None  # the measurement fixes the past
        stamp_ns = self.t0_ns + instant * self.period_ns
        report = self.report(stamp_ns)
        for channel in self.channels:
            channel.stats.skipped_reports += skipped
            channel.stats.tick(now_ns, stamp_ns if by_timer else None)
        if instant == self._last:
            self.done = True
            return Output(None, (report,), True)
        self.sample += 1
        for index, channel in enumerate(self.channels):
            channel.stats.sent(stamp_ns, stamp_ns)
            heard_ns = self._heard_ns[index]
            age_s = math.inf if heard_ns is None else (now_ns - heard_ns) * 1e-9
            if age_s > self.command_timeout_s and channel.power_pu != 0:
                # The command held until now, when its age is found beyond the timeout: zero from here.
                self.advance_to(self._elapsed_s(now_ns))
                self.line.force(index, instant - 1, 0.0)
                channel.stats.command_timeouts += 1
        return Output(report, (report,), False)

    def start(self, now_ns: int) -> Output | None:
        """Instant 0, reported as if by the timer."""
        return self.due(now_ns, by_timer=True)

    def on_timer(self, now_ns: int) -> Output | None:
        """The reporting timer fired."""
        return self.due(now_ns, by_timer=True)

    def interrupt(self, now_ns: int) -> Output | None:
        """Something happens now (a fault starts): report an instant passed unreported, bring the physics to now."""
        output = self.due(now_ns)
        self.advance_to(self._elapsed_s(now_ns))
        return output

    def command(self, index: int, stamp_ns: int, power_pu: float, arrival_ns: int, seal: bytes | None = None,
                sealed_stamp_ns: int | None = None) -> tuple[Verdict | None, Output | None]:
        """A command for channel ``index`` (``seal``: its authentication, over ``sealed_stamp_ns`` if given, as
        :meth:`Channel.admit`): its verdict (None once the run is over),
        and an instant found unreported.

        An instant whose tick is late is reported first, with the powers in force at it.
        """
        output = self.due(arrival_ns)
        if self.done:
            return None, output
        channel = self.channels[index]
        verdict, power = channel.admit(stamp_ns, power_pu, arrival_ns, seal=seal, sealed_stamp_ns=sealed_stamp_ns)
        if power is not None:
            self.advance_to(self._elapsed_s(arrival_ns))
            if verdict is Verdict.APPLIED:
                k = (stamp_ns - self.t0_ns) // self.period_ns
                if self.line.send(index, k, k * self.period_s, power, self.t_s) is not None:
                    self._heard_ns[index] = arrival_ns
            else:  # the stand-down
                self.line.force(index, self.sample - 2, power)
            if self._all_answered():
                # Integrate now, while the loop is idle, up to the next reporting instant (the powers
                # hold until the next commands, which answer that instant's measurement): the tick
                # then only publishes. Profiled: this takes the RK4 (10 steps at 100/s, 0.2-0.4 ms)
                # off the measurement -> command latency. Only once every generator has answered:
                # with N generators an earlier integrate-ahead would be redone N - 1 times a period.
                self._ahead = (self.t_s, self.state, self.line.snapshot())
                self.advance_to(self.sample * self.period_s)
        return verdict, output

    def _all_answered(self) -> bool:
        """Every channel has answered the latest measurement sent: no command is due before the next instant."""
        latest_ns = self.t0_ns + (self.sample - 1) * self.period_ns
        return all(channel.stats.is_answered(latest_ns) for channel in self.channels)


class LockstepStepper(_Loop):
    """Lockstep: simulated time; sample k+1 comes only when every channel answered sample k, or at the timeout.

    Sample instants are exact multiples of the period (``sample * period_s``),
    as in the offline sampled simulation, which it reproduces to rounding.
    With a link, the answer to sample k takes effect at t_k + d_k in simulated
    time (a delay of more than a period is a delay line: later periods are
    integrated piecewise with the commands then in force) or is lost (the
    command in force stays); either way it completes the handshake. A
    timeout's zero takes effect at once.
    """

    def __init__(self, integrate, state, channels, duration_s: float, period_s: float, timeout_s: float,
                 link: Link = NO_LINK, store: EnergyStore | None = None):
        super().__init__(integrate, state, channels, duration_s, link, store)
        self.period_s = period_s
        self.timeout_s = timeout_s
        # The generators' measurements go out together: one turnaround a sample, the one distribution every
        # channel reports (added once, where each channel's own copy took N adds a sample).
        self.turnaround = TimingDistribution(0, 100_000_000)
        for channel in self.channels:
            channel.stats.turnaround = self.turnaround
        self.awaited_ns: int | None = None
        self._answered: set[int] = set()
        self._arrival_ns: int | None = None

    def start(self, now_ns: int) -> Output:
        """Sample 0: publish /clock and its measurement, then call :meth:`sent`."""
        return Output(self._next_sample(), (), False)

    def _next_sample(self) -> Report:
        self.t_s = self.sample * self.period_s
        self.awaited_ns = ns_from_seconds(self.t_s)
        self._answered = set()
        return self.report(self.awaited_ns)

    def interrupt(self, now_ns: int) -> None:
        """Something happens now (a fault starts): in simulated time, that is at the current sample."""

    def sent(self, wall_ns: int) -> None:
        """The awaited sample's measurement left the plant at ``wall_ns``."""
        for channel in self.channels:
            channel.stats.sent(self.awaited_ns, wall_ns)
        if self._arrival_ns is not None:
            self.turnaround.add(wall_ns - self._arrival_ns)
        self._arrival_ns = None

    def command(self, index: int, stamp_ns: int, power_pu: float, arrival_ns: int, seal: bytes | None = None,
                sealed_stamp_ns: int | None = None) -> tuple[Verdict | None, Output | None]:
        """A command for channel ``index`` (``seal``: its authentication, over ``sealed_stamp_ns`` if given, as
        :meth:`Channel.admit`); the sample it completes, if it was the
        last answer awaited."""
        if self.done or self.awaited_ns is None:
            return None, None
        channel = self.channels[index]
        verdict, power = channel.admit(stamp_ns, power_pu, arrival_ns, self.awaited_ns, seal, sealed_stamp_ns)
        if power is not None:
            self.line.send(index, self.sample, self.t_s, power, self.t_s)
            self._answered.add(index)
        if len(self._answered) < len(self.channels):
            return verdict, None
        self._arrival_ns = arrival_ns
        return verdict, self._complete()

    def on_timer(self, wall_ns: int) -> Output | None:
        """The watchdog: past ``timeout_s`` of wall time without every answer, zero for the silent ones, and step."""
        if self.done or self.awaited_ns is None:
            return None
        if (wall_ns - self.channels[0].stats.last_sent_wall_ns) * 1e-9 <= self.timeout_s:
            return None
        for index, channel in enumerate(self.channels):
            if index not in self._answered:
                channel.stats.deadline_misses += 1
                self.line.force(index, self.sample, 0.0)
        return self._complete()

    def _complete(self) -> Output:
        """Apply the powers over one period; the next measurement goes before the completed state.

        The loop waits for the measurement, nobody waits for the state
        (profiled: one publish less on the lockstep critical path).
        """
        completed = self.report(self.awaited_ns)
        self.awaited_ns = None
        self.advance_to((self.sample + 1) * self.period_s)
        self.sample += 1
        if self.duration_s > 0 and self.t_s >= self.duration_s - 1e-9:
            self.t_s = self.sample * self.period_s
            self.done = True
            return Output(None, (completed, self.report(ns_from_seconds(self.t_s))), True)
        return Output(self._next_sample(), (completed,), False)


class PmuSensor:
    """What a PMU reads from the true state: Gaussian noise (seeded), then angle quantisation."""

    def __init__(self, angle_std_rad: float, speed_std_rad_s: float, quantisation_rad: float, seed: int):
        self.angle_std_rad, self.speed_std_rad_s = angle_std_rad, speed_std_rad_s
        self.quantisation_rad = quantisation_rad
        self._rng = np.random.default_rng(seed)
        #: No noise and no quantisation: :meth:`read` returns the true state.
        self.exact = angle_std_rad == speed_std_rad_s == quantisation_rad == 0

    def read(self, delta_rad: float, speed_rad_s: float) -> tuple[float, float]:
        """``(delta rad, speed deviation rad/s)`` as measured."""
        if self.angle_std_rad > 0:
            delta_rad += self._rng.normal(0.0, self.angle_std_rad)
        if self.speed_std_rad_s > 0:
            speed_rad_s += self._rng.normal(0.0, self.speed_std_rad_s)
        if self.quantisation_rad > 0:
            delta_rad = round(delta_rad / self.quantisation_rad) * self.quantisation_rad
        return delta_rad, speed_rad_s


class SubscriberWait:
    """Start when the loop's peers are there (plus a settling time for the rest of discovery), or give up.

    :meth:`poll` takes the counts the node sees and returns ``(state, level, text)``:
    state ``"wait"``, ``"start"`` or ``"give_up"``; a text to log at ``level``
    (``"info"`` when what is missing changed, ``"warning"`` when it is still
    missing ``log_period_s`` later, ``"error"`` when giving up), else None.
    """

    def __init__(self, wanted_readers: int, settle_s: float, timeout_s: float, since_ns: int,
                 log_period_s: float = 5.0):
        self.wanted_readers, self.settle_s = wanted_readers, settle_s
        self.timeout_s, self.log_period_s = timeout_s, log_period_s
        self._since_ns = since_ns
        self._logged: tuple[str, int] | None = None
        self._all_there_ns: int | None = None
        self.text = ""

    def poll(self, now_ns: int, readers: int, writers: int, reader_topic: str, writer_topic: str,
             released: bool = True, also_missing=()):
        """``released``: False while the plant holds its run for a release (``hold_until_released``);
        ``also_missing``: what else the node still waits for, in words."""
        missing = [f"{self.wanted_readers} subscriber(s) on {reader_topic} (has {readers})"] \
            if readers < self.wanted_readers else []
        missing += list(also_missing)
        if self.wanted_readers > 0 and writers < 1:
            missing.append(f"a controller publishing on {writer_topic} (has none)")
        if not released:
            missing.append("the release (SIGUSR1, hold_until_released)")
        if not missing:
            self._all_there_ns = self._all_there_ns or now_ns
            return ("start" if (now_ns - self._all_there_ns) * 1e-9 >= self.settle_s else "wait"), None, None
        self._all_there_ns = None
        waited_s = (now_ns - self._since_ns) * 1e-9
        self.text = "waiting for " + " and ".join(missing)
        if waited_s > self.timeout_s:
            return "give_up", "error", f"gave up after {waited_s:.1f} s {self.text}"
        same = self._logged is not None and self._logged[0] == self.text
        if same and (now_ns - self._logged[1]) * 1e-9 < self.log_period_s:
            return "wait", None, None
        self._logged = (self.text, now_ns)
        return "wait", "warning" if same else "info", f"{self.text} (waited {waited_s:.1f} s of {self.timeout_s:g})"
