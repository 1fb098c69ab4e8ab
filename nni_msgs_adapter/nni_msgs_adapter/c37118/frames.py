"""IEEE C37.118.2-2011 frames: configuration (CFG-1, CFG-2, CFG-3), header, command and data, both ways.

Where the layout comes from (read, not copied; the standard itself is not
public): the field tables quoted in cisagov/icsnpp-synchrophasor
``analyzer/synchrophasor.spicy`` (C37.118.2-2011 tables 2, 5, 8-14, cited
there table by table), the Kaitai descriptions of sonusz/PhasorToolBox
(``kaitai/cfg_3.ksy``: CFG-3's name fields, PHSCALE, location, service
class, window, group delay), Wireshark's ``epan/dissectors/packet-synphasor.c``
(CFG-3 offsets, the current-phasor bit 0x0800 of PHSCALE, CRC over the frame
less CHK) and the PyPI package ``pyc37``/``synchrophasor`` ``frame.py``; every
frame this module writes is decoded by two of them in the tests (pyc37 and
Debian's tshark).

The frame, big-endian throughout::

    SYNC      2  0xAA, then bit 7 = 0, frame type in bits 6-4 (0 data, 1 header,
                 2 CFG-1, 3 CFG-2, 4 command, 5 CFG-3), version in bits 3-0
                 (1 = 2005, 2 = 2011; this module writes 2, reads 1 and 2)
    FRAMESIZE 2  bytes of the whole frame, CHK included
    IDCODE    2  the stream's id (1..65534); for a command, the destination's
    SOC       4  seconds since 1970-01-01 UTC (no leap seconds)
    FRACSEC   4  time-quality byte (bit 6 leap second direction, 5 occurred,
                 4 pending, 3-0 message time quality code) and 24 bits of
                 fraction of second, in units of 1/TIME_BASE
    ...body...
    CHK       2  CRC-CCITT: polynomial 0x1021, initial 0xFFFF, no reflection,
                 no final xor, over every byte before it (``binascii.crc_hqx``)

What is supported, and what is not:

* CFG-1/CFG-2 and CFG-3 are written and read from one :class:`Config`;
  CFG-1/2 names are 16 ASCII bytes (longer names are cut, non-ASCII becomes
  ``?``), CFG-3 names are length-prefixed UTF-8 up to 255 bytes. CFG-3 is
  always written as one frame (CONT_IDX 0); a CFG-3 with CONT_IDX other than
  0 (a fragmented configuration) is refused on reading (reason
  ``unsupported``). CFG-3's PHSCALE angle adjustment and modification flags
  are written as 0 and not applied on reading; its scale factor Y is the
  PHUNIT scale (1e-5 per bit) for integer phasors, 1 for float ones.
* Data frames of every FORMAT (polar or rectangular, integer or float
  phasors; integer or float analogs and FREQ/DFREQ) are read; every FORMAT
  is written too, as long as the stations share one layout (FORMAT and
  channel counts), which our plants' do. FREQ is the actual frequency in Hz
  when float, the deviation from FNOM in mHz when integer; DFREQ is the
  ROCOF in Hz/s when float, Hz/s x 100 when integer. Float polar angles are
  written wrapped into [-pi, pi) as the standard asks. Integer analogs are
  returned unscaled (CFG-2's ANUNIT scaling is user-defined).
* Command frames: every CMD code is written and read; the meaning of an
  extended frame (CMD 8) is the user's and is returned as bytes.

Encoding a data frame is a precompiled numpy record layout per config
written in place into one preallocated frame buffer, then ``crc_hqx``: the
cost does not grow with the station count as a per-value pack would.
Measured (``python -m bench.c37118_server`` prints it), all-float FORMAT,
3 phasors, 1 analog and 1 digital word per station, per frame: 1 station
5.0 us, 10 stations 7.4 us, 52 stations 12.1 us (Python 3.11, numpy 2.4, on
the project's 2-core machine); integer FREQ/DFREQ adds about 5 us (the
rounding and saturation).

Pure python and numpy: no ROS import.
"""

from __future__ import annotations

import binascii
import enum
import math
import struct
from dataclasses import dataclass

import numpy as np

SYNC_BYTE = 0xAA
#: The version this module writes (bits 3-0 of SYNC): IEEE C37.118.2-2011.
VERSION_2011 = 2
#: Versions read: 2005 (1) and 2011 (2) share the layouts of every frame but CFG-3.
READABLE_VERSIONS = (1, 2)
#: SYNC, FRAMESIZE, IDCODE, SOC, FRACSEC.
COMMON_HEADER_BYTES = 14
CHK_BYTES = 2
#: An empty header frame: the smallest frame there is.
MIN_FRAME_BYTES = COMMON_HEADER_BYTES + CHK_BYTES
#: FRAMESIZE is 16 bits.
MAX_FRAME_BYTES = 0xFFFF
#: CRC-CCITT's initial value in C37.118 (the XMODEM variant starts from 0).
CRC_INITIAL = 0xFFFF
#: Resolution of FRACSEC we write by default: microseconds, what most PMUs use.
DEFAULT_TIME_BASE = 1_000_000
NS_PER_S = 1_000_000_000
#: Reporting rates (frames/s) C37.118.1 allows for each nominal frequency (Hz).
ALLOWED_REPORTING_RATES = {50: (10, 25, 50, 100), 60: (10, 12, 15, 20, 30, 60, 120)}
#: CFG-1/2 name width (bytes).
NAME_BYTES = 16
#: CFG-3 name fields are length-prefixed with one byte.
MAX_NAME_BYTES = 255
#: Station names carried by CFG-3 for PMUs: G_PMU_ID.
GLOBAL_PMU_ID_BYTES = 16
#: CFG-3 PMU_LAT/LON/ELEV for an unspecified location.
UNSPECIFIED_LOCATION = math.inf

_HEAD = struct.Struct(">BBHHII")
_U16 = struct.Struct(">H")
_CFG12_STATION_FIXED = struct.Struct(">16sHHHHH")
_CFG3_STATION_COUNTS = struct.Struct(">HHHH")
_CFG3_PHSCALE = struct.Struct(">HBBff")
_CFG3_ANSCALE = struct.Struct(">ff")
_CFG3_TAIL = struct.Struct(">fffcii")
_FNOM_CFGCNT = struct.Struct(">HH")
_TIMEBASE_NUMPMU = struct.Struct(">IH")


class FrameType(enum.IntEnum):
    """Frame type, bits 6-4 of SYNC's second byte."""

    DATA = 0
    HEADER = 1
    CFG1 = 2
    CFG2 = 3
    COMMAND = 4
    CFG3 = 5


CONFIG_TYPES = (FrameType.CFG1, FrameType.CFG2, FrameType.CFG3)


class Command(enum.IntEnum):
    """CMD word of a command frame (PDC to PMU); the other codes are reserved or user-designated."""

    DATA_OFF = 1
    DATA_ON = 2
    SEND_HEADER = 3
    SEND_CFG1 = 4
    SEND_CFG2 = 5
    SEND_CFG3 = 6
    EXTENDED = 8


class FrameError(ValueError):
    """A frame refused on reading; ``reason`` is one word, usable as a counter name.

    Reasons: ``truncated`` (fewer bytes than the frame needs), ``bad_sync``
    (first byte not 0xAA or bit 7 of the second set), ``unknown_type`` (frame
    type 6 or 7), ``bad_version`` (version not 1 or 2), ``bad_framesize``
    (FRAMESIZE below 16, or not what the buffer or the configuration says),
    ``oversized`` (FRAMESIZE beyond the reader's bound), ``bad_crc``,
    ``wrong_idcode``, ``wrong_type`` (a frame of another type than asked for),
    ``bad_body`` (fields that contradict each other or run past the frame),
    ``bad_fracsec`` (a fraction of second not below TIME_BASE),
    ``unsupported`` (a fragmented CFG-3).
    """

    REASONS = ("truncated", "bad_sync", "unknown_type", "bad_version", "bad_framesize", "oversized", "bad_crc",
               "wrong_idcode", "wrong_type", "bad_body", "bad_fracsec", "unsupported")

    def __init__(self, reason: str, detail: str):
        if reason not in self.REASONS:
            raise ValueError(f"unknown frame error reason {reason!r}")
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def crc_ccitt(data) -> int:
    """C37.118's CHK of ``data`` (bytes-like): CRC-CCITT, polynomial 0x1021, initial 0xFFFF, no reflection."""
    return binascii.crc_hqx(data, CRC_INITIAL)


# --- time ------------------------------------------------------------------------------------


def split_instant_ns(instant_ns: int, time_base: int) -> tuple[int, int]:
    """(SOC, fraction) of an instant in ns since 1970 UTC, the fraction in units of 1/``time_base``.

    Rounded to the nearest unit of 1/time_base, halves up (an instant
    0.5 unit short of a whole second becomes the next SOC, fraction 0). With
    the default TIME_BASE of 1 000 000 an instant is stamped to the nearest
    microsecond; a TIME_BASE that is a multiple of 600 stamps every instant
    k / rate of every allowed reporting rate exactly.
    """
    if not 1 <= time_base < 1 << 24:
        raise ValueError(f"TIME_BASE must be within [1, 2**24 - 1], got {time_base!r}")
    soc, remainder_ns = divmod(int(instant_ns), NS_PER_S)
    fraction = (remainder_ns * time_base + NS_PER_S // 2) // NS_PER_S
    if fraction == time_base:
        soc, fraction = soc + 1, 0
    if not 0 <= soc < 1 << 32:
        raise ValueError(f"instant {instant_ns} ns is outside what SOC holds (1970 to 2106)")
    return soc, fraction


def instant_ns_from(soc: int, fraction: int, time_base: int) -> int:
    """The instant (ns since 1970 UTC) of SOC and a fraction in units of 1/``time_base``, to the nearest ns (halves up)."""
    return soc * NS_PER_S + (fraction * NS_PER_S + time_base // 2) // time_base


def time_quality_byte(code: int = 0, *, leap_second_pending: bool = False, leap_second_occurred: bool = False,
                      leap_second_deleted: bool = False) -> int:
    """FRACSEC's top byte: message time quality ``code`` (0 locked to UTC, 1..11 within 10**(code-10) s, 15 fault)
    and the leap second flags."""
    if not 0 <= code <= 15:
        raise ValueError(f"message time quality code must be within [0, 15], got {code!r}")
    return code | leap_second_pending << 4 | leap_second_occurred << 5 | leap_second_deleted << 6


def check_reporting_rate(rate: int, nominal_hz: int) -> int:
    """``rate`` (frames/s) if C37.118.1 allows it at ``nominal_hz``; ValueError naming the allowed set otherwise."""
    if nominal_hz not in ALLOWED_REPORTING_RATES:
        raise ValueError(f"nominal frequency must be 50 or 60 Hz, got {nominal_hz!r}")
    allowed = ALLOWED_REPORTING_RATES[nominal_hz]
    if rate not in allowed:
        listed = ", ".join(str(r) for r in allowed)
        raise ValueError(f"reporting rate {rate!r} frames/s is not one C37.118 allows at {nominal_hz} Hz: {listed}")
    return rate


# --- STAT --------------------------------------------------------------------------------------

#: STAT bits 15-14.
DATA_GOOD, DATA_PMU_ERROR, DATA_TEST_MODE, DATA_PMU_ERROR_DO_NOT_USE = 0, 1, 2, 3
#: STAT bits 8-6, PMU time quality: 0 not used, 1 < 100 ns, 2 < 1 us, 3 < 10 us, 4 < 100 us, 5 < 1 ms,
#: 6 < 10 ms, 7 > 10 ms or unknown.
PMU_TIME_QUALITY_NOT_USED, PMU_TIME_QUALITY_UNKNOWN = 0, 7
#: STAT bits 3-0, trigger reason (8-15 are user-defined).
(TRIGGER_MANUAL, TRIGGER_MAGNITUDE_LOW, TRIGGER_MAGNITUDE_HIGH, TRIGGER_PHASE_ANGLE_DIFF, TRIGGER_FREQUENCY,
 TRIGGER_ROCOF, _TRIGGER_RESERVED, TRIGGER_DIGITAL) = range(8)


@dataclass(frozen=True)
class Stat:
    """A data frame's STAT word, one per station, field by field."""

    data_error: int = DATA_GOOD
    sync_lost: bool = False
    sorted_by_arrival: bool = False
    trigger: bool = False
    config_changed: bool = False
    data_modified: bool = False
    pmu_time_quality: int = PMU_TIME_QUALITY_NOT_USED
    unlocked_time: int = 0
    trigger_reason: int = TRIGGER_MANUAL

    def __post_init__(self):
        for name, value, high in (("data_error", self.data_error, 3), ("pmu_time_quality", self.pmu_time_quality, 7),
                                  ("unlocked_time", self.unlocked_time, 3), ("trigger_reason", self.trigger_reason, 15)):
            if not 0 <= value <= high:
                raise ValueError(f"STAT {name} must be within [0, {high}], got {value!r}")

    @property
    def word(self) -> int:
        return (self.data_error << 14 | self.sync_lost << 13 | self.sorted_by_arrival << 12 | self.trigger << 11
                | self.config_changed << 10 | self.data_modified << 9 | self.pmu_time_quality << 6
                | self.unlocked_time << 4 | self.trigger_reason)

    @property
    def data_valid(self) -> bool:
        """Bits 15-14 clear: good measurement data (anything else says: do not use, or no information)."""
        return self.data_error == DATA_GOOD

    @classmethod
    def from_word(cls, word: int) -> Stat:
        return cls(word >> 14 & 3, bool(word >> 13 & 1), bool(word >> 12 & 1), bool(word >> 11 & 1),
                   bool(word >> 10 & 1), bool(word >> 9 & 1), word >> 6 & 7, word >> 4 & 3, word & 15)


# --- configuration -----------------------------------------------------------------------------


@dataclass(frozen=True)
class DataFormat:
    """A station's FORMAT word: how its phasors, analogs and FREQ/DFREQ travel in data frames."""

    polar: bool = True
    phasor_float: bool = True
    analog_float: bool = True
    freq_float: bool = True

    @property
    def word(self) -> int:
        return self.polar | self.phasor_float << 1 | self.analog_float << 2 | self.freq_float << 3

    @classmethod
    def from_word(cls, word: int) -> DataFormat:
        return cls(bool(word & 1), bool(word & 2), bool(word & 4), bool(word & 8))


#: CFG-3 phasor component codes (type indication bits 2-0).
ZERO_SEQUENCE, POSITIVE_SEQUENCE, NEGATIVE_SEQUENCE, PHASE_A, PHASE_B, PHASE_C = 0, 1, 2, 4, 5, 6
#: CFG-1/2 ANUNIT kinds.
ANALOG_POINT_ON_WAVE, ANALOG_RMS, ANALOG_PEAK = 0, 1, 2


def _check_name(kind: str, name: str) -> None:
    if not isinstance(name, str) or len(name.encode("utf-8")) > MAX_NAME_BYTES:
        raise ValueError(f"{kind} name must be a string of at most {MAX_NAME_BYTES} UTF-8 bytes, got {name!r}")


@dataclass(frozen=True)
class PhasorChannel:
    """One phasor: its name, voltage or current, PHUNIT scale (1e-5 V or A per bit, integer data only), component."""

    name: str
    is_current: bool = False
    scale: int = 1
    component: int = POSITIVE_SEQUENCE

    def __post_init__(self):
        _check_name("phasor", self.name)
        if not 0 <= self.scale < 1 << 24:
            raise ValueError(f"phasor {self.name!r} PHUNIT scale must be within [0, 2**24 - 1], got {self.scale!r}")
        if self.component not in (ZERO_SEQUENCE, POSITIVE_SEQUENCE, NEGATIVE_SEQUENCE, PHASE_A, PHASE_B, PHASE_C):
            raise ValueError(f"phasor {self.name!r} component must be a CFG-3 component code, got {self.component!r}")


@dataclass(frozen=True)
class AnalogChannel:
    """One analog value: its name, ANUNIT kind (point-on-wave, rms, peak) and user-defined 24-bit signed scale."""

    name: str
    kind: int = ANALOG_RMS
    scale: int = 1

    def __post_init__(self):
        _check_name("analog", self.name)
        if not 0 <= self.kind <= 255:
            raise ValueError(f"analog {self.name!r} ANUNIT kind must be within [0, 255], got {self.kind!r}")
        if not -(1 << 23) <= self.scale < 1 << 23:
            raise ValueError(f"analog {self.name!r} ANUNIT scale must be a 24-bit signed integer, got {self.scale!r}")


@dataclass(frozen=True)
class DigitalWord:
    """One 16-bit digital status word: a name per bit (bit 0 first), its normal state and its valid bits."""

    bit_names: tuple[str, ...]
    normal_mask: int = 0
    valid_mask: int = 0xFFFF

    def __post_init__(self):
        if len(self.bit_names) != 16:
            raise ValueError(f"a digital word names its 16 bits, got {len(self.bit_names)} names")
        for name in self.bit_names:
            _check_name("digital bit", name)
        for mask in (self.normal_mask, self.valid_mask):
            if not 0 <= mask <= 0xFFFF:
                raise ValueError(f"digital word masks are 16-bit, got {mask!r}")


@dataclass(frozen=True)
class Station:
    """One PMU (a block of a data frame): names, FORMAT, channels, FNOM, CFGCNT, and CFG-3's extra fields.

    ``latitude_deg``, ``longitude_deg``, ``elevation_m`` are WGS 84, infinity
    when unspecified; ``service_class`` is C37.118.1's M or P;
    ``window_us`` and ``group_delay_us`` describe the measurement filter.
    """

    name: str
    idcode: int
    phasors: tuple[PhasorChannel, ...] = ()
    analogs: tuple[AnalogChannel, ...] = ()
    digitals: tuple[DigitalWord, ...] = ()
    data_format: DataFormat = DataFormat()
    nominal_hz: int = 50
    config_count: int = 0
    global_pmu_id: bytes = bytes(GLOBAL_PMU_ID_BYTES)
    latitude_deg: float = UNSPECIFIED_LOCATION
    longitude_deg: float = UNSPECIFIED_LOCATION
    elevation_m: float = UNSPECIFIED_LOCATION
    service_class: str = "P"
    window_us: int = 0
    group_delay_us: int = 0

    def __post_init__(self):
        _check_name("station", self.name)
        if not 1 <= self.idcode <= 65534:
            raise ValueError(f"station {self.name!r} IDCODE must be within [1, 65534], got {self.idcode!r}")
        if self.nominal_hz not in (50, 60):
            raise ValueError(f"station {self.name!r} nominal frequency must be 50 or 60 Hz, got {self.nominal_hz!r}")
        if not 0 <= self.config_count <= 0xFFFF:
            raise ValueError(f"station {self.name!r} CFGCNT must be 16-bit, got {self.config_count!r}")
        if len(self.global_pmu_id) != GLOBAL_PMU_ID_BYTES:
            raise ValueError(f"station {self.name!r} G_PMU_ID must be {GLOBAL_PMU_ID_BYTES} bytes")
        if self.service_class not in ("M", "P"):
            raise ValueError(f"station {self.name!r} service class must be 'M' or 'P', got {self.service_class!r}")
        for name, value in (("window", self.window_us), ("group delay", self.group_delay_us)):
            if not -(1 << 31) <= value < 1 << 31:
                raise ValueError(f"station {self.name!r} {name} must be a 32-bit signed count of us, got {value!r}")
        if not self.data_format.phasor_float and any(p.scale == 0 for p in self.phasors):
            raise ValueError(f"station {self.name!r} sends integer phasors: every PHUNIT scale must be positive")

    @property
    def layout(self) -> tuple:
        """What fixes the station's block in a data frame."""
        return self.data_format, len(self.phasors), len(self.analogs), len(self.digitals)


@dataclass(frozen=True)
class Config:
    """A data stream's configuration: its IDCODE, TIME_BASE, DATA_RATE and stations (in data frame order).

    ``data_rate`` is frames per second when positive, seconds per frame when
    negative (C37.118's DATA_RATE); :func:`check_reporting_rate` is the
    stricter check a PMU applies to its own rate.
    """

    idcode: int
    stations: tuple[Station, ...]
    data_rate: int
    time_base: int = DEFAULT_TIME_BASE

    def __post_init__(self):
        if not 1 <= self.idcode <= 65534:
            raise ValueError(f"stream IDCODE must be within [1, 65534], got {self.idcode!r}")
        if not 1 <= len(self.stations) <= 0xFFFF:
            raise ValueError(f"a stream has 1 to 65535 stations, got {len(self.stations)}")
        if not 1 <= self.time_base < 1 << 24:
            raise ValueError(f"TIME_BASE must be within [1, 2**24 - 1], got {self.time_base!r}")
        if self.data_rate == 0 or not -32767 <= self.data_rate <= 32767:
            raise ValueError(f"DATA_RATE must be a nonzero 16-bit signed integer, got {self.data_rate!r}")

    @property
    def data_frame_bytes(self) -> int:
        return COMMON_HEADER_BYTES + sum(_station_dtype(s).itemsize for s in self.stations) + CHK_BYTES


# --- decoded frames ----------------------------------------------------------------------------


@dataclass(frozen=True)
class FrameHead:
    """The fields every frame has."""

    frame_type: FrameType
    version: int
    framesize: int
    idcode: int
    soc: int
    fraction: int
    time_quality: int


@dataclass(frozen=True)
class CommandFrame:
    head: FrameHead
    command: int
    extended: bytes = b""


@dataclass(frozen=True)
class HeaderFrame:
    head: FrameHead
    text: str


@dataclass(frozen=True)
class ConfigFrame:
    head: FrameHead
    config: Config


@dataclass(frozen=True)
class StationReading:
    """One station's block of a data frame in physical units: polar phasors, Hz, Hz/s."""

    stat: int
    magnitudes: tuple[float, ...]
    angles_rad: tuple[float, ...]
    frequency_hz: float
    rocof_hz_per_s: float
    analogs: tuple[float, ...]
    digitals: tuple[int, ...]


@dataclass(frozen=True)
class DataFrame:
    head: FrameHead
    instant_ns: int
    stations: tuple[StationReading, ...]


# --- the common frame ------------------------------------------------------------------------------


def _finish(buffer: bytearray) -> bytes:
    """Write FRAMESIZE (already counted in ``buffer``, CHK included) and CHK; return the frame."""
    buffer[-2:] = _U16.pack(crc_ccitt(memoryview(buffer)[:-2]))
    return bytes(buffer)


def _frame(frame_type: FrameType, idcode: int, soc: int, fracsec: int, body: bytes) -> bytes:
    size = COMMON_HEADER_BYTES + len(body) + CHK_BYTES
    if size > MAX_FRAME_BYTES:
        raise ValueError(f"a {frame_type.name} frame of {size} bytes does not fit FRAMESIZE's 65535")
    buffer = bytearray(size)
    _HEAD.pack_into(buffer, 0, SYNC_BYTE, frame_type << 4 | VERSION_2011, size, idcode, soc, fracsec)
    buffer[COMMON_HEADER_BYTES:-CHK_BYTES] = body
    return _finish(buffer)


def _stamp(instant_ns: int, time_base: int, time_quality: int) -> tuple[int, int]:
    soc, fraction = split_instant_ns(instant_ns, time_base)
    return soc, time_quality << 24 | fraction


def read_head(frame, max_frame_bytes: int = MAX_FRAME_BYTES) -> FrameHead:
    """Check one whole frame's SYNC, FRAMESIZE (against the buffer and ``max_frame_bytes``) and CHK; its head.

    ``frame`` must hold exactly one frame. Raises :class:`FrameError`.
    """
    if len(frame) < 4:
        raise FrameError("truncated", f"{len(frame)} bytes do not hold SYNC and FRAMESIZE")
    if frame[0] != SYNC_BYTE or frame[1] & 0x80:
        raise FrameError("bad_sync", f"SYNC {frame[0]:02x}{frame[1]:02x}")
    kind, version = frame[1] >> 4, frame[1] & 0x0F
    if kind > FrameType.CFG3:
        raise FrameError("unknown_type", f"frame type {kind}")
    if version not in READABLE_VERSIONS:
        raise FrameError("bad_version", f"version {version}")
    size = _U16.unpack_from(frame, 2)[0]
    if size < MIN_FRAME_BYTES:
        raise FrameError("bad_framesize", f"FRAMESIZE {size} is below the {MIN_FRAME_BYTES} bytes of any frame")
    if size > max_frame_bytes:
        raise FrameError("oversized", f"FRAMESIZE {size} is beyond the bound of {max_frame_bytes} bytes")
    if len(frame) < size:
        raise FrameError("truncated", f"{len(frame)} bytes of a {size}-byte frame")
    if len(frame) > size:
        raise FrameError("bad_framesize", f"FRAMESIZE {size} but {len(frame)} bytes")
    expected = crc_ccitt(memoryview(frame)[:-CHK_BYTES])
    received = _U16.unpack_from(frame, size - CHK_BYTES)[0]
    if expected != received:
        raise FrameError("bad_crc", f"CHK {received:04x}, computed {expected:04x}")
    _, _, _, idcode, soc, fracsec = _HEAD.unpack_from(frame)
    return FrameHead(FrameType(kind), version, size, idcode, soc, fracsec & 0xFFFFFF, fracsec >> 24)


def _checked_head(frame, expected_type, idcode):
    head = read_head(frame)
    if expected_type is not None and head.frame_type not in expected_type:
        raise FrameError("wrong_type", f"a {head.frame_type.name} frame")
    if idcode is not None and head.idcode != idcode:
        raise FrameError("wrong_idcode", f"IDCODE {head.idcode}, expected {idcode}")
    return head


# --- command and header frames -------------------------------------------------------------------


def encode_command(idcode: int, command: int, instant_ns: int, *, extended: bytes = b"",
                   time_base: int = DEFAULT_TIME_BASE) -> bytes:
    """A command frame to the stream ``idcode``, stamped ``instant_ns`` (ns since 1970 UTC)."""
    if not 0 <= command <= 0xFFFF:
        raise ValueError(f"CMD must be 16-bit, got {command!r}")
    soc, fracsec = _stamp(instant_ns, time_base, 0)
    return _frame(FrameType.COMMAND, idcode, soc, fracsec, _U16.pack(command) + bytes(extended))


def decode_command(frame, idcode: int | None = None) -> CommandFrame:
    head = _checked_head(frame, (FrameType.COMMAND,), idcode)
    if head.framesize < MIN_FRAME_BYTES + 2:
        raise FrameError("bad_body", "a command frame without CMD")
    body = bytes(frame[COMMON_HEADER_BYTES:-CHK_BYTES])
    return CommandFrame(head, _U16.unpack_from(body)[0], body[2:])


def encode_header(idcode: int, text: str, instant_ns: int, *, time_base: int = DEFAULT_TIME_BASE) -> bytes:
    """A header frame: free ASCII text about the stream (non-ASCII characters become ``?``)."""
    soc, fracsec = _stamp(instant_ns, time_base, 0)
    return _frame(FrameType.HEADER, idcode, soc, fracsec, text.encode("ascii", "replace"))


def decode_header(frame, idcode: int | None = None) -> HeaderFrame:
    head = _checked_head(frame, (FrameType.HEADER,), idcode)
    return HeaderFrame(head, bytes(frame[COMMON_HEADER_BYTES:-CHK_BYTES]).decode("ascii", "replace"))


# --- configuration frames ------------------------------------------------------------------------


def _name16(name: str) -> bytes:
    return name.encode("ascii", "replace")[:NAME_BYTES].ljust(NAME_BYTES, b" ")


def _name_field(name: str) -> bytes:
    raw = name.encode("utf-8")
    return bytes([len(raw)]) + raw


def _channel_names(station: Station) -> list[str]:
    return ([p.name for p in station.phasors] + [a.name for a in station.analogs]
            + [bit for word in station.digitals for bit in word.bit_names])


def _cfg12_station(station: Station) -> bytes:
    parts = [_CFG12_STATION_FIXED.pack(_name16(station.name), station.idcode, station.data_format.word,
                                       len(station.phasors), len(station.analogs), len(station.digitals))]
    parts += [_name16(name) for name in _channel_names(station)]
    parts += [struct.pack(">I", p.is_current << 24 | p.scale) for p in station.phasors]
    parts += [struct.pack(">I", a.kind << 24 | a.scale & 0xFFFFFF) for a in station.analogs]
    parts += [struct.pack(">HH", d.normal_mask, d.valid_mask) for d in station.digitals]
    parts.append(_FNOM_CFGCNT.pack(station.nominal_hz == 50, station.config_count))
    return b"".join(parts)


def _cfg3_station(station: Station) -> bytes:
    fmt = station.data_format
    parts = [_name_field(station.name), _U16.pack(station.idcode), station.global_pmu_id,
             _CFG3_STATION_COUNTS.pack(fmt.word, len(station.phasors), len(station.analogs), len(station.digitals))]
    parts += [_name_field(name) for name in _channel_names(station)]
    parts += [_CFG3_PHSCALE.pack(0, p.is_current << 3 | p.component, 0,
                                 1.0 if fmt.phasor_float else p.scale * 1e-5, 0.0) for p in station.phasors]
    parts += [_CFG3_ANSCALE.pack(1.0 if fmt.analog_float else float(a.scale), 0.0) for a in station.analogs]
    parts += [struct.pack(">HH", d.normal_mask, d.valid_mask) for d in station.digitals]
    parts.append(_CFG3_TAIL.pack(station.latitude_deg, station.longitude_deg, station.elevation_m,
                                 station.service_class.encode("ascii"), station.window_us, station.group_delay_us))
    parts.append(_FNOM_CFGCNT.pack(station.nominal_hz == 50, station.config_count))
    return b"".join(parts)


def encode_config(config: Config, frame_type: FrameType, instant_ns: int) -> bytes:
    """CFG-1, CFG-2 or CFG-3 of ``config``, stamped ``instant_ns`` (ns since 1970 UTC)."""
    if frame_type not in CONFIG_TYPES:
        raise ValueError(f"{frame_type!r} is not a configuration frame type")
    cfg3 = frame_type == FrameType.CFG3
    station_block = _cfg3_station if cfg3 else _cfg12_station
    body = b"".join([_U16.pack(0) if cfg3 else b"", _TIMEBASE_NUMPMU.pack(config.time_base, len(config.stations)),
                     *(station_block(s) for s in config.stations), struct.pack(">h", config.data_rate)])
    soc, fracsec = _stamp(instant_ns, config.time_base, 0)
    return _frame(frame_type, config.idcode, soc, fracsec, body)


class _Cursor:
    """Reads a frame's body front to back; running past its end is a ``bad_body``."""

    def __init__(self, frame):
        self.data = memoryview(frame)[:-CHK_BYTES]
        self.at = COMMON_HEADER_BYTES

    def take(self, n: int) -> bytes:
        if self.at + n > len(self.data):
            raise FrameError("bad_body", f"a field runs {self.at + n - len(self.data)} bytes past the frame's end")
        chunk = bytes(self.data[self.at:self.at + n])
        self.at += n
        return chunk

    def unpack(self, layout: struct.Struct) -> tuple:
        return layout.unpack(self.take(layout.size))

    def name16(self) -> str:
        return self.take(NAME_BYTES).decode("ascii", "replace").rstrip(" \x00")

    def name_field(self) -> str:
        return self.take(self.take(1)[0]).decode("utf-8", "replace")


def _read_station(cursor: _Cursor, cfg3: bool) -> Station:
    if cfg3:
        name, idcode = cursor.name_field(), cursor.unpack(_U16)[0]
        global_pmu_id = cursor.take(GLOBAL_PMU_ID_BYTES)
        format_word, n_ph, n_an, n_dg = cursor.unpack(_CFG3_STATION_COUNTS)
    else:
        raw_name, idcode, format_word, n_ph, n_an, n_dg = cursor.unpack(_CFG12_STATION_FIXED)
        name = raw_name.decode("ascii", "replace").rstrip(" \x00")
        global_pmu_id = bytes(GLOBAL_PMU_ID_BYTES)
    read_name = cursor.name_field if cfg3 else cursor.name16
    names = [read_name() for _ in range(n_ph + n_an + 16 * n_dg)]
    data_format = DataFormat.from_word(format_word)
    phasors, analogs = [], []
    for name_ph in names[:n_ph]:
        if cfg3:
            _, type_indication, _, scale_factor, _ = cursor.unpack(_CFG3_PHSCALE)
            is_current, component = bool(type_indication & 0x08), type_indication & 0x07
            scale = 1 if data_format.phasor_float else max(1, round(scale_factor / 1e-5))
        else:
            unit = struct.unpack(">I", cursor.take(4))[0]
            is_current, component, scale = bool(unit >> 24), POSITIVE_SEQUENCE, unit & 0xFFFFFF
        phasors.append(PhasorChannel(name_ph, is_current, scale, component))
    for name_an in names[n_ph:n_ph + n_an]:
        if cfg3:
            magnitude_scale, _ = cursor.unpack(_CFG3_ANSCALE)
            kind, scale = ANALOG_RMS, int(max(-(1 << 23), min((1 << 23) - 1, round(magnitude_scale))))
        else:
            unit = struct.unpack(">I", cursor.take(4))[0]
            kind, scale = unit >> 24, (unit & 0xFFFFFF) - ((unit & 0x800000) << 1)
        analogs.append(AnalogChannel(name_an, kind, scale))
    bit_names = names[n_ph + n_an:]
    digitals = [DigitalWord(tuple(bit_names[16 * k:16 * k + 16]), *struct.unpack(">HH", cursor.take(4)))
                for k in range(n_dg)]
    extras = {}
    if cfg3:
        latitude, longitude, elevation, service_class, window, group_delay = cursor.unpack(_CFG3_TAIL)
        extras = dict(global_pmu_id=global_pmu_id, latitude_deg=latitude, longitude_deg=longitude,
                      elevation_m=elevation, service_class=service_class.decode("ascii", "replace"),
                      window_us=window, group_delay_us=group_delay)
    fnom, config_count = cursor.unpack(_FNOM_CFGCNT)
    return Station(name, idcode, tuple(phasors), tuple(analogs), tuple(digitals), data_format,
                   50 if fnom & 1 else 60, config_count, **extras)


def decode_config(frame, idcode: int | None = None) -> ConfigFrame:
    """A CFG-1, CFG-2 or CFG-3 frame (version 1 or 2) back into its :class:`Config`."""
    head = _checked_head(frame, CONFIG_TYPES, idcode)
    cfg3 = head.frame_type == FrameType.CFG3
    cursor = _Cursor(frame)
    if cfg3 and cursor.unpack(_U16)[0] != 0:
        raise FrameError("unsupported", "a fragmented CFG-3 (CONT_IDX other than 0)")
    time_base_word, n_stations = cursor.unpack(_TIMEBASE_NUMPMU)
    try:
        stations = tuple(_read_station(cursor, cfg3) for _ in range(n_stations))
        data_rate = struct.unpack(">h", cursor.take(2))[0]
        if cursor.at != len(cursor.data):
            raise FrameError("bad_body", f"{len(cursor.data) - cursor.at} bytes left after DATA_RATE")
        return ConfigFrame(head, Config(head.idcode, stations, data_rate, time_base_word & 0xFFFFFF))
    except ValueError as error:
        if isinstance(error, FrameError):
            raise
        raise FrameError("bad_body", str(error)) from None


# --- data frames -----------------------------------------------------------------------------------


def _station_dtype(station: Station) -> np.dtype:
    """A station's block of a data frame as one packed big-endian numpy record."""
    fmt = station.data_format
    if fmt.phasor_float:
        pair = [("a", ">f4"), ("b", ">f4")]
    else:
        pair = [("a", ">u2" if fmt.polar else ">i2"), ("b", ">i2")]
    freq = ">f4" if fmt.freq_float else ">i2"
    return np.dtype([("stat", ">u2"), ("phasors", pair, (len(station.phasors),)), ("freq", freq), ("dfreq", freq),
                     ("analog", ">f4" if fmt.analog_float else ">i2", (len(station.analogs),)),
                     ("digital", ">u2", (len(station.digitals),))])


def _runs(config: Config) -> list[tuple[int, int]]:
    """(first station, count) of each run of consecutive stations that share one layout."""
    runs, start = [], 0
    for k in range(1, len(config.stations) + 1):
        if k == len(config.stations) or config.stations[k].layout != config.stations[start].layout:
            runs.append((start, k - start))
            start = k
    return runs


def _phasor_scales(stations) -> np.ndarray:
    """Magnitude (or real/imaginary) per bit of integer phasors, (stations, phasors)."""
    return np.array([[p.scale * 1e-5 for p in s.phasors] for s in stations], dtype=float).reshape(len(stations), -1)


def _nominal(stations) -> np.ndarray:
    return np.array([s.nominal_hz for s in stations], dtype=float)


def _to_int16(values, unsigned: bool = False) -> np.ndarray:
    """Nearest integers, saturated to the 16-bit range (-32767..32767, or 0..65535): never wrapped."""
    return np.clip(np.rint(values), 0 if unsigned else -32767, 65535 if unsigned else 32767)


@dataclass
class Measurements:
    """One data frame's values, station by station (row k is station k), in physical units.

    ``stat`` (stations,) STAT words (see :class:`Stat`); ``magnitude`` and
    ``angle_rad`` (stations, phasors) polar phasors (any angle: it is wrapped
    into [-pi, pi) on the wire); ``frequency_hz`` and ``rocof_hz_per_s``
    (stations,) the actual frequency and its rate of change; ``analog``
    (stations, analogs); ``digital`` (stations, digital words) 16-bit words.
    Any field may be given as a scalar or a row that broadcasts.
    """

    stat: object
    magnitude: object
    angle_rad: object
    frequency_hz: object
    rocof_hz_per_s: object
    analog: object = 0.0
    digital: object = 0


class DataFrameEncoder:
    """Writes the data frames of one config, fast: the frame buffer and its record layout are made once.

    The stations must share one layout (FORMAT and channel counts).
    ``encode`` reuses one buffer: one encoder per thread.
    """

    def __init__(self, config: Config):
        if len(_runs(config)) != 1:
            raise ValueError("the encoder writes stations that share one layout (FORMAT and channel counts)")
        self.config = config
        self.frame_bytes = config.data_frame_bytes
        if self.frame_bytes > MAX_FRAME_BYTES:
            raise ValueError(f"a data frame of {self.frame_bytes} bytes does not fit FRAMESIZE's 65535")
        self._buffer = bytearray(self.frame_bytes)
        self._records = np.frombuffer(self._buffer, dtype=_station_dtype(config.stations[0]),
                                      count=len(config.stations), offset=COMMON_HEADER_BYTES)
        self._format = config.stations[0].data_format
        self._nominal_hz = _nominal(config.stations)
        self._scale = _phasor_scales(config.stations)
        self._first_byte = FrameType.DATA << 4 | VERSION_2011

    def encode(self, instant_ns: int, values: Measurements, time_quality: int = 0) -> bytes:
        """The data frame of the sample taken at ``instant_ns`` (ns since 1970 UTC); ``time_quality`` is
        FRACSEC's top byte (:func:`time_quality_byte`)."""
        soc, fraction = split_instant_ns(instant_ns, self.config.time_base)
        _HEAD.pack_into(self._buffer, 0, SYNC_BYTE, self._first_byte, self.frame_bytes, self.config.idcode, soc,
                        time_quality << 24 | fraction)
        records, fmt = self._records, self._format
        records["stat"] = values.stat
        phasors = records["phasors"]
        if fmt.polar:
            angle = np.remainder(np.add(values.angle_rad, math.pi), 2 * math.pi) - math.pi
            first, second = values.magnitude, angle
        else:
            first = np.multiply(values.magnitude, np.cos(values.angle_rad))
            second = np.multiply(values.magnitude, np.sin(values.angle_rad))
        if fmt.phasor_float:
            phasors["a"], phasors["b"] = first, second
        else:
            phasors["a"] = _to_int16(np.divide(first, self._scale), unsigned=fmt.polar)
            phasors["b"] = _to_int16(np.multiply(second, 1e4) if fmt.polar else np.divide(second, self._scale))
        if fmt.freq_float:
            records["freq"], records["dfreq"] = values.frequency_hz, values.rocof_hz_per_s
        else:
            records["freq"] = _to_int16(np.multiply(np.subtract(values.frequency_hz, self._nominal_hz), 1e3))
            records["dfreq"] = _to_int16(np.multiply(values.rocof_hz_per_s, 1e2))
        records["analog"] = values.analog if fmt.analog_float else _to_int16(values.analog)
        records["digital"] = values.digital
        return _finish(self._buffer)


class DataFrameDecoder:
    """Reads the data frames of one config (any FORMAT, stations of any layouts) into physical units."""

    def __init__(self, config: Config):
        self.config = config
        self.frame_bytes = config.data_frame_bytes
        self._runs = []
        offset = COMMON_HEADER_BYTES
        for first, count in _runs(config):
            stations = config.stations[first:first + count]
            dtype = _station_dtype(stations[0])
            self._runs.append((offset, count, dtype, stations[0].data_format, _nominal(stations),
                               _phasor_scales(stations)))
            offset += count * dtype.itemsize

    def decode(self, frame) -> DataFrame:
        """Raises :class:`FrameError` for a frame that is not a valid data frame of this config."""
        head = _checked_head(frame, (FrameType.DATA,), self.config.idcode)
        if head.framesize != self.frame_bytes:
            raise FrameError("bad_framesize", f"a data frame of {head.framesize} bytes, the config says "
                                              f"{self.frame_bytes}")
        if head.fraction >= self.config.time_base:
            raise FrameError("bad_fracsec", f"fraction {head.fraction} is not below TIME_BASE "
                                            f"{self.config.time_base}")
        readings = []
        for offset, count, dtype, fmt, nominal_hz, scale in self._runs:
            records = np.frombuffer(frame, dtype=dtype, count=count, offset=offset)
            first = records["phasors"]["a"].astype(float)
            second = records["phasors"]["b"].astype(float)
            if not fmt.phasor_float:
                first = first * scale
                second = second * 1e-4 if fmt.polar else second * scale
            if fmt.polar:
                magnitude, angle = first, second
            else:
                magnitude, angle = np.hypot(first, second), np.arctan2(second, first)
            freq, dfreq = records["freq"].astype(float), records["dfreq"].astype(float)
            if not fmt.freq_float:
                freq, dfreq = nominal_hz + freq * 1e-3, dfreq * 1e-2
            readings += map(StationReading, records["stat"].tolist(), map(tuple, magnitude.tolist()),
                            map(tuple, angle.tolist()), freq.tolist(), dfreq.tolist(),
                            map(tuple, records["analog"].astype(float).tolist()),
                            map(tuple, records["digital"].tolist()))
        return DataFrame(head, instant_ns_from(head.soc, head.fraction, self.config.time_base), tuple(readings))

