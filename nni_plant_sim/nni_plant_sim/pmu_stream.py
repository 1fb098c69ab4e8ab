"""A plant's IEEE C37.118.2 PMU stream: its parameters, its server, and what each sample puts in a data frame.

The plant nodes (:mod:`.plant_node_base`) hand each reported sample here
after publishing it; what the stream carries (channels, time, STAT) is
:mod:`nni_msgs_adapter.c37118.profile`, the server (its own I/O thread, one
bounded queue per PDC, commands) :mod:`nni_msgs_adapter.c37118.server`.
:meth:`PlantStream.offer` never blocks: it computes and encodes the frame
only while a PDC has data on (the plant's own phasors, ~20 us for a 10-station
network, measured in ``bench.c37118``), hands it to the server's thread and
returns; a PDC that stalls or never reads loses its own frames, counted, and
costs the plant nothing more.

Time: each frame is stamped with its sample's instant (lockstep: the
simulated time from the profile's epoch; realtime: the wall clock), to the
microsecond. A controller fed through the stream answers with that stamp,
which at rates whose period is no whole microsecond (and for any realtime
instant) is the plant's own rounded to 1 us: :meth:`PlantStream.plant_stamp`
maps it back to the stamp of the sample it answers, for the plant's command
path. STAT and FRACSEC's time quality from the clock: lockstep's simulated
clock is not UTC; realtime, the kernel's answer (:mod:`~nni_msgs_adapter.c37118.clock_sync`).
The trigger bit goes to the first sample at or after a disturbance's start
and each of its breakpoints.

Pure python and numpy (threads and sockets): no ROS import.
"""

from __future__ import annotations

import collections
import math

import numpy as np

from nni_msgs_adapter.c37118 import frames as c37
from nni_msgs_adapter.c37118 import profile
from nni_msgs_adapter.c37118.clock_sync import ClockState, KernelClock
from nni_msgs_adapter.c37118.server import PmuServer
from nni_msgs_adapter.ros.ros_params import Spec

#: Sample stamps remembered for :meth:`PlantStream.plant_stamp`: far more than the answers a plant awaits at once.
STAMPS_KEPT = 64
#: The plant parameters of its stream (locked once the node is up: the server is listening).
STREAM_PARAMETERS = ("pmu_port", "pmu_host", "pmu_idcode", "pmu_freq_format", "pmu_wait_for_pdcs")
#: ``pmu_port`` of a plant without a stream.
NO_STREAM = -1
#: Prefix of the JSON line with the stream's final counters (:meth:`PlantStream.summary`), printed at exit.
SUMMARY_PREFIX_STREAM = "c37118_server summary: "
#: The lockstep clock as the stream states it: simulated time, not synchronised to UTC.
SIMULATED_CLOCK = ClockState(False, math.inf, True)
#: The SMIB plant's one station.
SMIB_STATION = "SMIB generator"


def network_station_names(namespaces, machines) -> list[str]:
    """A network generator's station name: its namespace, machine and bus (``gen3 G3 bus 32``)."""
    return [f"{namespace.strip('/')} {machine.replace('@', ' bus ')}"
            for namespace, machine in zip(namespaces, machines)]


def stream_parameters(defaults: dict) -> tuple[Spec, ...]:
    """The stream's node parameters, their defaults from ``defaults`` (the node's YAML)."""
    return (
        Spec("pmu_port", defaults["pmu_port"], "Serve the PMU measurements as an IEEE C37.118.2 stream over TCP on "
             "this port (C37.118's customary port is 4712; 0: a free one, logged); -1: no stream.", -1, 65535),
        Spec("pmu_host", defaults["pmu_host"], "The address the C37.118 stream listens on (loopback by default: "
             "name an interface's address, or 0.0.0.0 for all, to serve PDCs on other hosts)."),
        Spec("pmu_idcode", defaults["pmu_idcode"], "The stream's IDCODE (one station per generator, station "
             "IDCODEs 1..N).", 1, 65534),
        Spec("pmu_freq_format", defaults["pmu_freq_format"], "FREQ/DFREQ in the data frames: integer (mHz from "
             "FNOM, Hz/s x 100: what every PDC reads) or float (Hz, Hz/s).", choices=profile.FREQ_FORMATS),
        Spec("pmu_wait_for_pdcs", defaults["pmu_wait_for_pdcs"], "Start the run only once this many PDCs have "
             "turned data on (and the subscribers are there); 0: do not wait for any.", 0, 64),
    )


class PlantStream:
    """One plant's stream: ``names`` of its generators (station names), served at ``address`` (host, port)."""

    def __init__(self, address: tuple[str, int], idcode: int, names, rate_hz: float, nominal_hz: float,
                 terminal: bool, freq_format: str, lockstep: bool, plant: str, clock: KernelClock | None = None):
        self.config = profile.stream_config(idcode, names, rate_hz, nominal_hz, terminal, freq_format)
        self.server = PmuServer(self.config, profile.header_text(plant, lockstep, terminal), host=address[0],
                                port=address[1])
        self.lockstep = lockstep
        self._address = address
        self._clock = None if lockstep else clock or KernelClock()
        self._last_t_s = -math.inf
        self._disturbed = False
        self._stamps: dict[int, int] = {}
        self._stamp_order: collections.deque = collections.deque()
        self._reported: dict = {}

    @classmethod
    def from_values(cls, values: dict, names, nominal_hz: float, terminal: bool, plant: str) -> PlantStream | None:
        """The stream the plant parameters ask for, None for ``pmu_port`` -1; ValueError names what cannot be."""
        if values["pmu_port"] == NO_STREAM:
            if values["pmu_wait_for_pdcs"]:
                raise ValueError("pmu_wait_for_pdcs needs pmu_port (a C37.118 stream to wait on)")
            return None
        return cls((values["pmu_host"], values["pmu_port"]), values["pmu_idcode"], names,
                   values["pmu_rate_hz"], nominal_hz, terminal, values["pmu_freq_format"],
                   values["mode"] == "lockstep", plant)

    # --- life cycle ---------------------------------------------------------------------------

    def start(self) -> str:
        """Listen; the line that says where. ValueError (one line) when the address cannot be listened on."""
        try:
            host, port = self.server.start()
        except OSError as error:
            raise ValueError(f"the C37.118 stream cannot listen on {profile.address_text(*self._address)}: "
                             f"{error.strerror or error}") from None
        stations = len(self.config.stations)
        return (f"C37.118 PMU stream IDCODE {self.config.idcode} ({stations} station{'s' * (stations > 1)}, "
                f"{self.config.data_rate} frames/s) listening on {profile.address_text(host, port)}")

    def stop(self) -> None:
        self.server.stop()

    @property
    def where(self) -> str:
        return profile.address_text(*self.server.address)

    @property
    def streaming(self) -> int:
        """PDCs with data on."""
        return self.server.streaming

    # --- the plant's side ----------------------------------------------------------------------

    def disturbed(self) -> None:
        """A disturbance starts now: the next sample carries the trigger."""
        self._disturbed = True

    def offer(self, stamp_ns: int, t_s: float, breakpoints, measure) -> None:
        """The sample stamped ``stamp_ns`` at simulated ``t_s``, its scenario's ``breakpoints`` (s);
        ``measure(stat)`` gives its :class:`~nni_msgs_adapter.c37118.frames.Measurements` (called only while
        a PDC has data on), ``stat`` the STAT words of a station with valid data and of one without
        (:func:`station_values`)."""
        trigger = self._disturbed or any(self._last_t_s < b <= t_s for b in breakpoints)
        self._last_t_s, self._disturbed = t_s, False
        wire_ns = profile.wire_stamp_ns(stamp_ns, self.lockstep, self.config.time_base)
        if wire_ns != stamp_ns:
            self._remember(wire_ns, stamp_ns)
        if not self.server.streaming:
            return
        clock = self._clock.state() if self._clock is not None else SIMULATED_CLOCK
        values = measure(tuple(profile.stat_word(valid, clock.synchronised, trigger) for valid in (True, False)))
        self.server.offer(profile.stream_instant_ns(stamp_ns, self.lockstep), values,
                          profile.time_quality(clock.synchronised, clock.error_s))

    def _remember(self, wire_ns: int, stamp_ns: int) -> None:
        self._stamps[wire_ns] = stamp_ns
        self._stamp_order.append(wire_ns)
        if len(self._stamp_order) > STAMPS_KEPT:
            self._stamps.pop(self._stamp_order.popleft(), None)

    def plant_stamp(self, stamp_ns: int) -> int:
        """The stamp of the sample a command stamped ``stamp_ns`` answers: a stamp read from the stream is
        mapped back to the plant's own, any other is kept."""
        return self._stamps.get(stamp_ns, stamp_ns)

    # --- what the node reports -----------------------------------------------------------------

    def events(self) -> list[str]:
        """Lines to log: PDCs connected, gone, data on or off."""
        return [f"C37.118: {line}" for line in self.server.events()]

    def status(self) -> tuple[str, str, dict]:
        """``(level, message, values)`` of the stream's status on /diagnostics: WARN while frames are dropped
        for a PDC or commands rejected (since the last status), else OK."""
        counters = self.server.counters()
        values = {key: counters[key] for key in ("connected", "connections", "disconnected", "refused", "offered",
                                                 "frames_sent", "frames_dropped", "handoff_dropped", "redundant")}
        values["address"] = self.where
        values["streaming"] = self.streaming
        values.update({f"command_{name}": n for name, n in sorted(counters["commands"].items())})
        values.update({f"rejected_{reason}": n for reason, n in sorted(counters["rejected"].items())})
        values["pdcs"] = "; ".join(f"{pdc['address']} data {'on' if pdc['data_on'] else 'off'}, sent "
                                   f"{pdc['frames_sent']}, dropped {pdc['frames_dropped']}" for pdc in counters["pdcs"])
        watched = {key: n for key, n in values.items() if key in ("frames_dropped", "handoff_dropped", "refused")
                   or key.startswith("rejected_")}
        grew = [key for key, n in watched.items() if n > self._reported.get(key, 0)]
        self._reported = watched
        message = f"serving {self.where} to {counters['connected']} PDC(s), {self.streaming} with data on"
        return ("WARN", f"{message}; grew: {', '.join(grew)}", values) if grew else ("OK", message, values)


    def summary(self) -> dict:
        """The stream's address, its totals and, per PDC (connected or gone, in the order they came), its
        address and the frames sent (configuration and header included) and dropped: what a demo reports."""
        counters = self.server.counters()
        pdcs = [{key: pdc[key] for key in ("address", "frames_sent", "frames_dropped", "bytes_sent")}
                for pdc in (*counters["departed"], *counters["pdcs"])]
        totals = {key: counters[key] for key in ("offered", "connections", "refused", "frames_sent", "frames_dropped",
                                                 "handoff_dropped")}
        return {"address": self.where, **totals, "pdcs": pdcs}


def station_values(stat, magnitude, angle_rad, frequency_hz, rocof_hz_per_s, analog) -> c37.Measurements:
    """One frame's values (row k: station k); ``stat`` the STAT words (data valid, not valid): valid where
    every value of the station's row is finite."""
    magnitude, angle_rad = np.atleast_2d(magnitude), np.atleast_2d(angle_rad)
    frequency_hz, rocof_hz_per_s = np.atleast_1d(frequency_hz), np.atleast_1d(rocof_hz_per_s)
    analog = np.atleast_2d(analog)
    finite = (np.isfinite(magnitude).all(axis=1) & np.isfinite(angle_rad).all(axis=1) & np.isfinite(frequency_hz)
              & np.isfinite(rocof_hz_per_s) & np.isfinite(analog).all(axis=1))
    return c37.Measurements(np.where(finite, *stat), magnitude, angle_rad, frequency_hz, rocof_hz_per_s, analog)
