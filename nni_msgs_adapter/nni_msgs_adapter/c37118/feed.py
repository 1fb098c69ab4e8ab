"""From a C37.118 stream's station samples to the controllers' measurements: the PDC client node's core.

:class:`StationFeeds` takes what :class:`~.client.PdcClient` hands over (each
frame's :class:`~.client.StationSample` list) and gives, per station mapped
to a generator's namespace, the measurement the contract's ``pmu`` layout
carries (:data:`nni_msgs_adapter.ros.contract.TOPIC_C37118_PMU`):

* the stamp: the frame's SOC/FRACSEC (ns since 1970), lockstep with the
  profile's epoch taken off (:func:`.profile.stamp_from_instant`): the
  plant's simulated ns, to the microsecond;
* the angle: the named phasor's (default the plants' EMF, whose angle is the
  rotor angle), unwrapped from sample to sample (C37.118 sends float angles
  wrapped into [-pi, pi); a rotor that slips poles turns on), starting afresh
  on each new connection at the value on the wire;
* the speed deviation 2 pi (FREQ - FNOM), rad/s;
* the effort: the named analog (default the plants' P_E), NaN when the
  stream has none (a controller with g measured then refuses the sample).

The stream's rejections are the client core's (:class:`~.client.PdcSession`:
``bad_crc``, ``bad_sync``, ``wrong_idcode``, ``bad_framesize``, ``oversized``,
``truncated``, ``invalid_data``, ``time_backwards``, ``duplicate``, ``stale``,
``config_changed``, ``config_mismatch``: a configuration unlike the first,
or without a station per namespace with the named phasor and analog, which
:meth:`StationFeeds.config_fault` tells the client to refuse, ...); the feeds
add three of their own: ``missing_channel`` (a station without the named
phasor or analog: not behind a client given :meth:`StationFeeds.config_fault`),
``unmapped_station`` (a station beyond the namespaces given)
and ``implausible``: a sample whose angle step since the
station's last accepted one is not what its own frequency says, beyond
``plausible_step_rad``. IEEE C37.118.2 has no authentication, so this is the
stream's check of consistency: the angle advances at the speed deviation, so from
(t0, angle0, speed0) to (t1, angle1, speed1) the step is the trapezoid
(speed0 + speed1) (t1 - t0) / 2 to within (t1 - t0)^2 times the jump of the
acceleration (well under a milliradian at 50 frames/s for these machines),
and a bound of 0.1 rad (5.7 degrees) leaves room for a PMU's noise up to about
20 mrad (the bound over 5 standard deviations of the step). It catches an
angle that a man in the middle or a compromised PMU moves by more than the
bound without moving the frequency with it; it does not catch one that moves
both consistently, nor a small bias. An implausible sample is not fed to the
controller and not taken as the next reference; the first sample of a
connection is taken as it is. :meth:`StationFeeds.status` raises ERROR on
/diagnostics while ``implausible`` grows or while not connected, WARN while
another rejection grows.

Pure python: no ROS import.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from . import profile
from .counting import add
from .frames import Config

#: The feeds' own rejection reasons, beside the client core's.
FEED_REJECTIONS = ("missing_channel", "unmapped_station", "implausible")
#: Default bound on a sample's angle step beyond what its frequency explains, rad.
PLAUSIBLE_STEP_RAD = 0.1
#: The power channel of a feed told to read none: its effort is NaN.
_NO_ANALOG = -1


class Measurement(NamedTuple):
    """One station's sample for generator ``index`` (of the feeds' namespaces), in the ``pmu`` layout's units."""

    index: int
    stamp_ns: int
    angle_rad: float
    speed_rad_s: float
    power_pu: float


def unwrapped(previous_rad: float | None, wire_rad: float) -> float:
    """``wire_rad`` (within [-pi, pi]) moved by whole turns to lie within pi of ``previous_rad`` (None: as it is)."""
    if previous_rad is None:
        return wire_rad
    return previous_rad + math.remainder(wire_rad - previous_rad, 2.0 * math.pi)


def _index(names: list[str], name: str) -> int | None:
    return names.index(name) if name in names else None


class StationFeeds:
    """The stations of one stream, station k feeding generator k of ``count`` namespaces (data frame order)."""

    def __init__(self, count: int, lockstep: bool, angle_phasor: str = profile.EMF_PHASOR,
                 power_analog: str = profile.POWER_ANALOG, plausible_step_rad: float = PLAUSIBLE_STEP_RAD):
        self.count, self.lockstep, self.plausible_step_rad = count, lockstep, plausible_step_rad
        self.angle_phasor, self.power_analog = angle_phasor, power_analog
        self.rejected: dict[str, int] = {}
        self.published = 0
        self._config: Config | None = None
        self._channels: list[tuple[int, int | None] | None] = []
        self._last: list[tuple[int, float, float] | None] = [None] * count  # (instant ns, angle, speed) accepted
        self._connection = None
        self._reported: dict[str, int] = {}

    def _channels_of(self, station) -> tuple[int | None, int | None]:
        """The indexes of ``station``'s named phasor and analog (:data:`_NO_ANALOG` when none is named), each None
        if the station has no such channel."""
        phasors = [p.name for p in station.phasors]
        angle = _index(phasors, self.angle_phasor) if self.angle_phasor else (0 if phasors else None)
        power = _index([a.name for a in station.analogs], self.power_analog) if self.power_analog else _NO_ANALOG
        return angle, power

    def _configure(self, config: Config) -> None:
        """Which phasor and analog of each station (None: a station without the named phasor or analog)."""
        self._config, self._channels = config, []
        for station in config.stations:
            angle, power = self._channels_of(station)
            self._channels.append(None if angle is None or power is None else (angle, power))

    def config_fault(self, config: Config) -> str | None:
        """Why ``config`` is not the stream this node was set up for, or None: it must have a station for each
        namespace, each of those with the named phasor and analog (the client refuses any other:
        ``config_mismatch``). Stations beyond them are the PDC's others (counted ``unmapped_station``)."""
        if len(config.stations) < self.count:
            return f"the stream has {len(config.stations)} station(s), this node maps {self.count} namespace(s)"
        for station in config.stations[:self.count]:
            angle, power = self._channels_of(station)
            if angle is None:
                return f"station {station.name!r} has no phasor {self.angle_phasor or '(any)'!r}"
            if power is None:
                return f"station {station.name!r} has no analog {self.power_analog!r}"
        return None

    def take(self, samples, config: Config, connection: int) -> list[Measurement]:
        """The measurements of one frame's ``samples`` read with ``config`` on connection number ``connection``."""
        if config is not self._config:
            self._configure(config)
        if connection != self._connection:
            self._connection, self._last = connection, [None] * self.count
        taken = []
        for sample in samples:
            if sample.station >= self.count:
                add(self.rejected, "unmapped_station")
                continue
            channels = self._channels[sample.station]
            if channels is None:
                add(self.rejected, "missing_channel")
                continue
            angle_index, power_index = channels
            reading = sample.reading
            last = self._last[sample.station]
            angle = unwrapped(None if last is None else last[1], reading.angles_rad[angle_index])
            speed = 2.0 * math.pi * (reading.frequency_hz - config.stations[sample.station].nominal_hz)
            if last is not None and not self.plausible(last, sample.instant_ns, angle, speed):
                add(self.rejected, "implausible")
                continue
            self._last[sample.station] = (sample.instant_ns, angle, speed)
            taken.append(Measurement(sample.station, profile.stamp_from_instant(sample.instant_ns, self.lockstep),
                                     angle, speed,
                                     math.nan if power_index == _NO_ANALOG else reading.analogs[power_index]))
        self.published += len(taken)
        return taken

    def plausible(self, last: tuple[int, float, float], instant_ns: int, angle_rad: float, speed_rad_s: float) -> bool:
        """Whether the step from ``last`` (instant ns, angle, speed) to this sample is what the speeds explain."""
        expected = last[1] + 0.5 * (last[2] + speed_rad_s) * (instant_ns - last[0]) * 1e-9
        return abs(angle_rad - expected) <= self.plausible_step_rad

    def status(self, client: dict) -> tuple[str, str, dict]:
        """``(level, message, values)`` for /diagnostics from the client's counters (:meth:`.client.PdcClient.counters`):
        ERROR while not connected, WARN while a rejection grew since the last status, else OK."""
        rejected = dict(client["rejected"])
        for reason, n in self.rejected.items():
            add(rejected, reason, n)
        values = {"connected": client["connected"], "connections": client["connections"],
                  "connect_failures": client["connect_failures"], "samples": client["samples"],
                  "published": self.published,
                  **{f"frames_{kind}": n for kind, n in sorted(client["frames"].items())},
                  **{f"rejected_{reason}": n for reason, n in sorted(rejected.items())}}
        grew = sorted(reason for reason, n in rejected.items() if n > self._reported.get(reason, 0))
        self._reported = rejected
        if not client["connected"]:
            return "ERROR", "not connected to the PMU", values
        if "implausible" in grew:
            return "ERROR", (f"rejected: {', '.join(grew)} (an angle step its frequency does not explain, beyond "
                             f"{self.plausible_step_rad:g} rad)"), values
        if {"config_changed", "config_mismatch"} & set(grew):
            return "ERROR", f"rejected: {', '.join(grew)} (a configuration this node does not take)", values
        if grew:
            return "WARN", f"rejected: {', '.join(grew)}", values
        return "OK", "receiving", values
