"""Is the wall clock locked to UTC? The Linux kernel's own answer, read with ``adjtimex`` (no privilege needed).

A realtime PMU stream says in STAT bit 13 and FRACSEC's time quality whether
its time stamps are UTC (:mod:`.profile`). The kernel knows: NTP (chrony,
ntpd, systemd-timesyncd) or PTP daemons discipline it through ``adjtimex``,
which reports ``TIME_ERROR`` (and the ``STA_UNSYNC`` status bit) while no one
has, and otherwise its estimated error. ``adjtimex`` with ``modes = 0`` only
reads. Where it cannot be called (not Linux, no C library), the state is
unknown, which a stream reports as not synchronised: it cannot claim UTC.

The kernel's state changes slowly (a daemon's poll is 16 s to 17 min), so
:class:`KernelClock` reads it at most once per ``period_s``.
Pure python (ctypes): no ROS import.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import math
import time
from dataclasses import dataclass

#: adjtimex's return value while the clock is not synchronised (linux/timex.h).
_TIME_ERROR = 5
#: timex.status bit: the clock is not synchronised (linux/timex.h).
_STA_UNSYNC = 0x0040


class _Timeval(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_usec", ctypes.c_long)]


class _Timex(ctypes.Structure):
    """struct timex of linux/timex.h (glibc's layout), up to its reserved tail."""

    _fields_ = [("modes", ctypes.c_uint), ("offset", ctypes.c_long), ("freq", ctypes.c_long),
                ("maxerror", ctypes.c_long), ("esterror", ctypes.c_long), ("status", ctypes.c_int),
                ("constant", ctypes.c_long), ("precision", ctypes.c_long), ("tolerance", ctypes.c_long),
                ("time", _Timeval), ("tick", ctypes.c_long), ("ppsfreq", ctypes.c_long), ("jitter", ctypes.c_long),
                ("shift", ctypes.c_int), ("stabil", ctypes.c_long), ("jitcnt", ctypes.c_long),
                ("calcnt", ctypes.c_long), ("errcnt", ctypes.c_long), ("stbcnt", ctypes.c_long),
                ("tai", ctypes.c_int), ("reserved", ctypes.c_int * 11)]


@dataclass(frozen=True)
class ClockState:
    """``synchronised``: the kernel says its clock is disciplined to UTC; ``error_s``: its estimated error
    (inf when unknown); ``known``: the kernel could be asked."""

    synchronised: bool
    error_s: float
    known: bool

    def describe(self) -> str:
        if not self.known:
            return "clock synchronisation unknown (adjtimex unavailable): reported as not synchronised"
        if not self.synchronised:
            return "the kernel says the wall clock is not synchronised (no NTP/PTP lock)"
        return f"the kernel says the wall clock is synchronised, estimated error {self.error_s * 1e6:g} us"


UNKNOWN = ClockState(False, math.inf, False)


@functools.cache
def _adjtimex():
    """The C library's ``adjtimex``, or None. Looked up once: ``find_library`` runs ``ldconfig`` (milliseconds)."""
    try:
        return ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True).adjtimex
    except (OSError, AttributeError, TypeError):
        return None


def read_kernel_clock() -> ClockState:
    """The kernel's clock state now (``adjtimex`` with modes 0); :data:`UNKNOWN` where it cannot be called."""
    adjtimex = _adjtimex()
    if adjtimex is None:
        return UNKNOWN
    timex = _Timex()
    state = adjtimex(ctypes.byref(timex))
    if state < 0:
        return UNKNOWN
    synchronised = state != _TIME_ERROR and not timex.status & _STA_UNSYNC
    return ClockState(synchronised, timex.esterror * 1e-6 if synchronised else math.inf, True)


class KernelClock:
    """The kernel's clock state, read again at most every ``period_s`` (``read`` may be given for tests)."""

    def __init__(self, period_s: float = 10.0, read=read_kernel_clock, monotonic=time.monotonic):
        self._period_s, self._read, self._monotonic = period_s, read, monotonic
        self._read_at = -math.inf
        self._state = UNKNOWN

    def state(self) -> ClockState:
        now = self._monotonic()
        if now - self._read_at >= self._period_s:
            self._state, self._read_at = self._read(), now
        return self._state
