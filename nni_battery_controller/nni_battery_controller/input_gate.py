"""The controller's input gate: which PMU measurements become samples of the law, and why the others do not.

Pure (no ROS): the controller node hands in each measurement's stamp and
values with the time of its own reference clock, and gets a :class:`Verdict`
back. Finiteness is checked here, once, for the whole input path.

* malformed (the node could not read it), non-finite and implausible values;
* implausible stamps: further than ``tolerance_ns`` from the reference clock
  (realtime: the controller's wall clock; lockstep: /clock), plus the
  stream's offset (see re-anchoring);
* duplicates and stamps older than the last accepted one (out of order);
* a gap in the stream's own stamps longer than ``gap_ns``: accepted, but the
  law's state no longer describes the plant and is reset;
* silence (:meth:`InputGate.silence`): no measurement accepted for ``gap_ns``
  of wall time is a stale episode (the controller commands zero once).

Recovery instead of lock-out: after ``reanchor_after`` consecutive
rejections for the stamp (implausible or out of order, not duplicates), the
gate re-anchors on the stream: it takes the latest stamp as the new order
reference and the stream's offset from the reference clock as the new
expectation, accepts that measurement and asks for a reset. A single
far-future stamp (a rogue, or a PMU whose clock glitched once) is rejected as
implausible and changes nothing; a stream whose clock really jumped (or runs
beyond the tolerance from ours) is followed after ``reanchor_after`` samples.
"""

from __future__ import annotations

import enum
import math

#: Measurements beyond these are sensor faults, not a generator (a machine that
#: slips poles for minutes stays far below 1e6 rad); they are dropped and counted.
MAX_PLAUSIBLE_ANGLE_RAD = 1e6
MAX_PLAUSIBLE_SPEED_RAD_S = 1e4


class Verdict(enum.Enum):
    """What the gate decided; the value is the diagnostics counter it increments."""

    ACCEPTED = "samples"
    RESET = "resets"                        # accepted after a gap: the law restarts from steady state
    REANCHORED = "reanchors"                # accepted after too many stamp rejections: reset too
    MALFORMED = "malformed"
    NON_FINITE = "non_finite"
    IMPLAUSIBLE = "implausible"
    IMPLAUSIBLE_STAMP = "implausible_stamp"
    DUPLICATE = "duplicate"
    OUT_OF_ORDER = "out_of_order"

    @property
    def accepted(self) -> bool:
        """The measurement is a sample of the law."""
        return self in (Verdict.ACCEPTED, Verdict.RESET, Verdict.REANCHORED)

    @property
    def resets(self) -> bool:
        """The law's state must restart from steady state before this sample."""
        return self in (Verdict.RESET, Verdict.REANCHORED)


#: Every counter the gate keeps (``samples`` counts every accepted measurement).
COUNTERS = (*(verdict.value for verdict in Verdict), "stale_episodes")


class InputGate:
    """Decides on each measurement and counts every verdict (``counts``, keys :data:`COUNTERS`)."""

    def __init__(self, gap_ns: int, tolerance_ns: int, reanchor_after: int):
        self.configure(gap_ns, tolerance_ns, reanchor_after)
        self.last_stamp_ns: int | None = None
        self.offset_ns = 0  # the stream's stamps minus the reference clock, once re-anchored
        self._stamp_rejections = 0
        self.last_arrival_ns: int | None = None
        self.stale = False
        self.counts = dict.fromkeys(COUNTERS, 0)

    def configure(self, gap_ns: int, tolerance_ns: int, reanchor_after: int) -> None:
        """Set the bounds (at start, or changed before the controller is active)."""
        self.gap_ns, self.tolerance_ns, self.reanchor_after = gap_ns, tolerance_ns, reanchor_after

    def malformed(self) -> Verdict:
        """The node could not read the message (wrong joints or sizes)."""
        return self._count(Verdict.MALFORMED)

    def check(self, stamp_ns: int, delta_rad: float, speed_rad_s: float, reference_ns: int,
              arrival_ns: int) -> Verdict:
        """The verdict on one measurement; ``reference_ns``: the reference clock now; ``arrival_ns``: wall time."""
        verdict = self._check(stamp_ns, delta_rad, speed_rad_s, reference_ns)
        if verdict.accepted:
            self.last_arrival_ns, self.stale = arrival_ns, False
        return verdict

    def silence(self, wall_ns: int) -> int | None:
        """A stale episode starts: the stamp of the zero command to send (in the stream's time base), else None.

        Stamped at the instant the silence was noticed, after the last measurement:
        it answers no measurement (the plant applies it as a stand-down).
        """
        if self.stale or self.last_arrival_ns is None or wall_ns - self.last_arrival_ns <= self.gap_ns:
            return None
        self.stale = True
        self.counts["stale_episodes"] += 1
        return self.last_stamp_ns + wall_ns - self.last_arrival_ns

    def silence_check_in_ns(self, wall_ns: int) -> int:
        """From ``wall_ns``, how long until :meth:`silence` would start a stale episode: just past ``gap_ns`` after
        the last accepted measurement, or ``gap_ns`` while there is none to watch (none yet, stale already, or
        overdue: the caller stood down)."""
        if self.stale or self.last_arrival_ns is None:
            return self.gap_ns
        due_in = self.last_arrival_ns + self.gap_ns + 1 - wall_ns
        return due_in if due_in > 0 else self.gap_ns

    def _check(self, stamp_ns: int, delta_rad: float, speed_rad_s: float, reference_ns: int) -> Verdict:
        if not (math.isfinite(delta_rad) and math.isfinite(speed_rad_s)):
            return self._count(Verdict.NON_FINITE)
        if abs(delta_rad) > MAX_PLAUSIBLE_ANGLE_RAD or abs(speed_rad_s) > MAX_PLAUSIBLE_SPEED_RAD_S:
            return self._count(Verdict.IMPLAUSIBLE)
        if self.last_stamp_ns is not None and stamp_ns == self.last_stamp_ns:
            return self._count(Verdict.DUPLICATE)
        if abs(stamp_ns - reference_ns - self.offset_ns) > self.tolerance_ns:
            return self._reject_stamp(Verdict.IMPLAUSIBLE_STAMP, stamp_ns, reference_ns)
        if self.last_stamp_ns is not None and stamp_ns < self.last_stamp_ns:
            return self._reject_stamp(Verdict.OUT_OF_ORDER, stamp_ns, reference_ns)
        self._stamp_rejections = 0
        gap = self.last_stamp_ns is not None and stamp_ns - self.last_stamp_ns > self.gap_ns
        self.last_stamp_ns = stamp_ns
        self.counts["samples"] += 1
        return self._count(Verdict.RESET) if gap else Verdict.ACCEPTED

    def _reject_stamp(self, verdict: Verdict, stamp_ns: int, reference_ns: int) -> Verdict:
        self._stamp_rejections += 1
        if self._stamp_rejections < self.reanchor_after:
            return self._count(verdict)
        self._stamp_rejections = 0
        self.last_stamp_ns, self.offset_ns = stamp_ns, stamp_ns - reference_ns
        self.counts["samples"] += 1
        return self._count(Verdict.REANCHORED)

    def _count(self, verdict: Verdict) -> Verdict:
        self.counts[verdict.value] += 1
        return verdict
