"""The synchrophasor stream our plants serve: its channels, its clock, its STAT and how its server is named.

One definition read by both ends: the plants' PMU stream
(:mod:`nni_plant_sim.pmu_stream`), ``nni-replay --pmu-server`` and the PDC
client node (:mod:`.client_node`, through :mod:`.feed`), so that what one writes the other reads by
the same names.

* One data stream per plant (IDCODE a parameter, default 1), one station per
  generator (station IDCODE 1..N in generator order), FNOM the plant's
  nominal frequency, DATA_RATE its reporting rate.
* Phasors per station, floating-point polar, positive sequence, in per unit
  (C37.118 expects volts and amperes for float phasors: a PDC shows these
  values as pu): :data:`EMF_PHASOR`, the internal EMF E' behind the transient
  reactance, its angle the rotor angle delta exactly as the plant's ``pmu``
  topic reports it (the PMU's reading, noise and quantisation included) and
  the one the controllers use; for a network (:data:`TERMINAL_PHASORS`) the
  terminal voltage V_t (pu of the bus voltage base) and the current I_t
  injected by the machine (pu of the machine's rating).
* FREQ = f0 + delta'/(2 pi) from the measured speed deviation; DFREQ =
  delta''/(2 pi) Hz/s from the swing equation at the sample. Integer (FREQ in
  mHz from FNOM, DFREQ in Hz/s x 100) by default, what every PDC reads, or
  float (:data:`FREQ_FORMATS`).
* Analogs (float): :data:`POWER_ANALOG`, the electrical power P_E as on
  ``pmu`` (pu of the machine's rating), and :data:`BATTERY_ANALOG`, the
  battery power P_ST in force at the sample.
* Time: SOC/FRACSEC are the sample's instant, TIME_BASE 1 000 000 (stamps to
  the microsecond, rounded to the nearest: exact for every instant of the
  50 Hz rates and for 10 and 20 frames/s at 60 Hz; within 0.5 us for 12, 15,
  30, 60 and 120 frames/s, whose periods are no whole microseconds, and for
  any realtime instant). Realtime the instant is the wall clock; lockstep it
  is the simulated time from :data:`LOCKSTEP_EPOCH_NS` (2000-01-01 00:00:00
  UTC): simulated t = 0 s is SOC 946684800, FRACSEC 0.
* STAT (:func:`stat_word`): bits 15-14 00 (data valid) unless a value is not
  finite, then 11 (do not use); bit 13 set (PMU sync lost) unless the clock
  is locked to UTC (:mod:`.clock_sync`; never in lockstep); bit 11 (trigger)
  in the first sample at or after a disturbance's start and at each of its
  breakpoints (clearing, the end of a step), trigger reason 0 (manual: the
  disturbance is the operator's); bit 10 (configuration change) always 0:
  the stream's configuration is fixed for the plant's life (its parameters
  are locked once it is up). Bits 8-4 (PMU time quality, unlocked time) are
  written 0, "not used": pyc37, the Python PDC we test against, reads a
  stream with any other value there as broken; the clock's quality goes in
  FRACSEC's message time quality instead (:func:`time_quality`).

Pure python and numpy: no ROS import.
"""

from __future__ import annotations

import math

from . import frames as c37

#: Simulated t = 0 of a lockstep run on the wire: 2000-01-01 00:00:00 UTC, ns since 1970.
LOCKSTEP_EPOCH_NS = 946_684_800 * c37.NS_PER_S
EMF_PHASOR = "E' internal EMF"
TERMINAL_PHASORS = ("V terminal", "I terminal")
POWER_ANALOG = "P_E pu"
BATTERY_ANALOG = "P_ST battery pu"
#: How FREQ and DFREQ travel: integer (mHz from FNOM, Hz/s x 100; every PDC reads it) or float (Hz, Hz/s).
FREQ_FORMATS = ("integer", "float")
#: FRACSEC's message time quality code of a clock not locked to UTC (C37.118.2: clock failure, time not
#: reliable): a lockstep run's simulated clock, or a wall clock the kernel says is not synchronised.
TIME_NOT_RELIABLE = 15


def station(name: str, number: int, nominal_hz: int, terminal: bool, freq_format: str) -> c37.Station:
    """Generator ``number`` (1..N, its station IDCODE) named ``name`` (CFG-1/2 keep its first 16 characters)."""
    if freq_format not in FREQ_FORMATS:
        raise ValueError(f"FREQ format must be one of {', '.join(FREQ_FORMATS)}, got {freq_format!r}")
    phasors = (c37.PhasorChannel(EMF_PHASOR),)
    if terminal:
        phasors += (c37.PhasorChannel(TERMINAL_PHASORS[0]), c37.PhasorChannel(TERMINAL_PHASORS[1], is_current=True))
    return c37.Station(name, number, phasors, (c37.AnalogChannel(POWER_ANALOG), c37.AnalogChannel(BATTERY_ANALOG)),
                       (), c37.DataFormat(freq_float=freq_format == "float"), nominal_hz, 1)


def stream_config(idcode: int, names, rate_hz: float, nominal_hz: float, terminal: bool,
                  freq_format: str) -> c37.Config:
    """The stream of a plant whose generators are ``names``; ValueError for a rate C37.118 does not allow
    (:func:`check_stream_rate`)."""
    check_stream_rate(rate_hz, nominal_hz)
    stations = tuple(station(name, k + 1, int(nominal_hz), terminal, freq_format) for k, name in enumerate(names))
    return c37.Config(idcode, stations, int(rate_hz))


def check_stream_rate(rate_hz: float, nominal_hz: float) -> None:
    """ValueError (one line) unless ``nominal_hz`` is 50 or 60 and ``rate_hz`` a reporting rate C37.118.1
    allows there: what a plant, a demo and a replay check before they serve a stream."""
    if nominal_hz not in (50, 60):
        raise ValueError(f"a C37.118 stream needs a nominal frequency of 50 or 60 Hz, got {nominal_hz:g} Hz")
    if rate_hz != round(rate_hz):
        raise ValueError(f"reporting rate {rate_hz:g} frames/s is not one C37.118 allows at {nominal_hz:g} Hz: "
                         f"{', '.join(map(str, c37.ALLOWED_REPORTING_RATES[int(nominal_hz)]))}")
    c37.check_reporting_rate(int(rate_hz), int(nominal_hz))


def stream_instant_ns(stamp_ns: int, lockstep: bool) -> int:
    """The instant on the wire (ns since 1970 UTC) of a sample stamped ``stamp_ns`` on the plant's clock."""
    return stamp_ns + LOCKSTEP_EPOCH_NS if lockstep else stamp_ns


def stamp_from_instant(instant_ns: int, lockstep: bool) -> int:
    """The plant's clock (lockstep: simulated ns) of an instant read from the wire: :func:`stream_instant_ns` undone."""
    return instant_ns - LOCKSTEP_EPOCH_NS if lockstep else instant_ns


def wire_stamp_ns(stamp_ns: int, lockstep: bool, time_base: int = c37.DEFAULT_TIME_BASE) -> int:
    """What a reader of the stream gets back for a sample stamped ``stamp_ns``: the stamp rounded to 1/TIME_BASE."""
    instant_ns = stream_instant_ns(stamp_ns, lockstep)
    return stamp_from_instant(c37.instant_ns_from(*c37.split_instant_ns(instant_ns, time_base), time_base), lockstep)


def stat_word(valid: bool, synchronised: bool, trigger: bool) -> int:
    """A station's STAT (module docstring): data valid or do-not-use, PMU sync, trigger (reason manual)."""
    return c37.Stat(data_error=c37.DATA_GOOD if valid else c37.DATA_PMU_ERROR_DO_NOT_USE, sync_lost=not synchronised,
                    trigger=trigger, trigger_reason=c37.TRIGGER_MANUAL).word


def time_quality(synchronised: bool, error_s: float) -> int:
    """FRACSEC's time-quality byte: the code of a clock within ``error_s`` of UTC, else :data:`TIME_NOT_RELIABLE`.

    C37.118.2's codes: 0 locked to a UTC-traceable source, 1..11 within 10**(code - 10) s (1 ns .. 10 s);
    an error estimate above 10 s, or a clock that is not synchronised, is "not reliable".
    """
    if not synchronised or not math.isfinite(error_s) or error_s > 10.0:
        return c37.time_quality_byte(TIME_NOT_RELIABLE)
    code = 1 if error_s <= 1e-9 else min(11, max(1, math.ceil(math.log10(error_s) - 1e-12) + 10))
    return c37.time_quality_byte(code)


def parse_server_address(text: str, default_host: str = "127.0.0.1", what: str = "a C37.118 server address"
                         ) -> tuple[str, int]:
    """``(host, port)`` of ``[HOST:]PORT`` (an IPv6 host in brackets: ``[::1]:4712``); ValueError naming the text.

    Port 0 asks for a free port. Without a host, ``default_host`` (loopback): a stream leaves the machine
    only when the user names an address.
    """
    host, sep, port_text = text.strip().rpartition(":")
    host = host.strip("[]") if sep else default_host
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535 or (sep and not host):
        raise ValueError(f"{what} is [HOST:]PORT with a port 0..65535, got {text!r}")
    return host, int(port_text)


def address_text(host: str, port: int) -> str:
    """``host:port`` (``[host]:port`` for IPv6)."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def header_text(plant: str, lockstep: bool, terminal: bool) -> str:
    """The header frame: what the stream carries, in words (its time, each channel's meaning and unit)."""
    clock = (f"simulated time of a lockstep run from epoch {LOCKSTEP_EPOCH_NS // c37.NS_PER_S} s "
             "(2000-01-01T00:00:00Z = t 0 s); not UTC" if lockstep else "the sample's wall-clock instant")
    phasors = [f"{EMF_PHASOR!r}: internal EMF behind x'd, pu, angle = rotor angle delta as the plant's pmu "
               "topic reports it (rad, wrapped to [-pi, pi))"]
    if terminal:
        phasors += [f"{TERMINAL_PHASORS[0]!r}: terminal voltage, pu of the bus voltage base",
                    f"{TERMINAL_PHASORS[1]!r}: current the machine injects, pu of its rating"]
    return (f"{plant}. One station per generator. SOC/FRACSEC: {clock}; TIME_BASE 1000000. Phasors (polar, float, "
            f"per unit): {'; '.join(phasors)}. FREQ: f0 + speed deviation / 2 pi; DFREQ: rotor acceleration / 2 pi, "
            f"Hz/s. Analogs: {POWER_ANALOG!r} electrical power, {BATTERY_ANALOG!r} battery power in force, pu of "
            "the machine's rating. STAT: bit 13 set unless the clock is locked to UTC, bit 11 at a disturbance's "
            "start and breakpoints, bits 8-4 not used (time quality in FRACSEC).")
