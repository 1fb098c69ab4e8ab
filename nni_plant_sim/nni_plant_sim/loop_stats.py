"""Loop timing bookkeeping at the plant: latency, timer jitter, misses and drops.

Cheap and always on, in time and memory: each sample increments one bin of a
1 us histogram, and a summary (diagnostics, once a second, on the plant's
executor) costs the same after an hour as after a second. Profiled: keeping
every sample in a list and taking np.percentile of it cost 4 ms per summary
after 30 s at 1000 frames/s (four reporting periods of stall, once a second)
and 40 ms after 300,000 samples; the histogram's summary takes ~0.1 ms.
Pure python and numpy.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

#: How many recent samples remember their send time (answers to older ones are late anyway).
_REMEMBERED_SAMPLES = 256
#: Histogram resolution, ns: percentiles are exact to this.
RESOLUTION_NS = 1_000


class TimingDistribution:
    """Durations in ns (may be negative) counted in 1 us bins over [low_ns, high_ns); values outside kept exactly.

    Percentiles are nearest-rank: the bin's centre, or the exact value for one
    outside the binned range (rare by choice of the range).
    """

    def __init__(self, low_ns: int, high_ns: int):
        self.low_ns = low_ns
        self._counts = np.zeros((high_ns - low_ns) // RESOLUTION_NS, dtype=np.int64)
        self._below: list[int] = []
        self._above: list[int] = []
        self.count = 0
        self.max_ns: int | None = None
        self.max_abs_ns = 0

    def add(self, value_ns: int) -> None:
        """Count one duration, ns."""
        self.count += 1
        index = (value_ns - self.low_ns) // RESOLUTION_NS
        if index < 0:
            self._below.append(value_ns)
        elif index >= self._counts.size:
            self._above.append(value_ns)
        else:
            self._counts[index] += 1
        if self.max_ns is None or value_ns > self.max_ns:
            self.max_ns = value_ns
        self.max_abs_ns = max(self.max_abs_ns, abs(value_ns))

    def percentiles_ns(self, percents) -> list[float]:
        """Nearest-rank percentiles (0 < p <= 100), ns; empty distribution: ValueError."""
        if self.count == 0:
            raise ValueError("no values")
        below, above = sorted(self._below), sorted(self._above)
        cumulative = np.cumsum(self._counts)
        out = []
        for percent in percents:
            rank = max(1, math.ceil(percent / 100.0 * self.count))  # 1-based
            if rank <= len(below):
                out.append(float(below[rank - 1]))
            elif rank - len(below) <= cumulative[-1]:
                index = int(np.searchsorted(cumulative, rank - len(below)))
                out.append(self.low_ns + (index + 0.5) * RESOLUTION_NS)
            else:
                out.append(float(above[rank - len(below) - int(cumulative[-1]) - 1]))
        return out


class LoopStats:
    """Per-sample timing of the measurement -> command loop, seen from the plant.

    Latency of a sample: wall time from its measurement (realtime: its stamp,
    the reporting instant the state was measured at; lockstep: its
    publication) to the arrival of the command that answers it. Jitter: how
    late the reporting timer fired after the instant. A deadline miss: a
    reporting instant reached with the previous sample unanswered (lockstep: a
    timeout). A skipped report: a reporting instant that got no measurement
    because the timer fell more than a period behind. Turnaround (lockstep):
    the plant's own share of each cycle, from a command's arrival to the next
    measurement's publication (physics, /clock, the measurement itself).
    """

    def __init__(self):
        # Ranges: loop latency 0..100 ms, timer jitter -10..90 ms (a timer fires late, rarely early).
        self.latency = TimingDistribution(0, 100_000_000)
        self.jitter = TimingDistribution(-10_000_000, 90_000_000)
        self.turnaround = TimingDistribution(0, 100_000_000)
        self._sent_wall_ns: OrderedDict[int, int] = OrderedDict()
        self.last_sent_stamp_ns: int | None = None
        self.last_sent_wall_ns: int | None = None
        self.last_answered_stamp_ns: int | None = None
        self.last_answer_wall_ns: int | None = None
        self.late = 0
        self.deadline_misses = 0
        self.command_timeouts = 0
        self.duplicates = 0
        self.skipped_reports = 0
        self.measurements = 0

    def sent(self, stamp_ns: int, wall_ns: int) -> None:
        """A measurement with ``stamp_ns`` left the plant at ``wall_ns``."""
        self.measurements += 1
        self._sent_wall_ns[stamp_ns] = wall_ns
        if len(self._sent_wall_ns) > _REMEMBERED_SAMPLES:
            self._sent_wall_ns.popitem(last=False)
        self.last_sent_stamp_ns, self.last_sent_wall_ns = stamp_ns, wall_ns

    def tick(self, now_ns: int, ideal_ns: int | None) -> None:
        """A realtime reporting instant, reported at ``now_ns``: a miss if the last sample is unanswered.

        ``ideal_ns``: the instant, when the reporting timer fired for it (its
        jitter is recorded); None when something else reported it first.
        """
        if ideal_ns is not None:
            self.jitter.add(now_ns - ideal_ns)
        if self.last_sent_stamp_ns is not None and self.last_answered_stamp_ns != self.last_sent_stamp_ns:
            self.deadline_misses += 1

    def sent_wall_ns(self, stamp_ns: int) -> int | None:
        """Wall time the measurement stamped ``stamp_ns`` left the plant, or None if it sent none (or forgot it)."""
        return self._sent_wall_ns.get(stamp_ns)

    def is_answered(self, stamp_ns: int) -> bool:
        """True if an answer to this or a later measurement has been counted already."""
        return self.last_answered_stamp_ns is not None and stamp_ns <= self.last_answered_stamp_ns

    def answered(self, stamp_ns: int, arrival_ns: int) -> bool:
        """A command stamped ``stamp_ns`` arrived. False for a duplicate or out-of-order answer (not to be applied).

        Only answers to measurements this plant sent order the answers and
        count as such. A command that answers none (the controller's zero on
        stale data, stamped after the last measurement it saw; an answer to a
        sample too old to be remembered) is to be applied but leaves the
        bookkeeping alone: were it to count, its stamp could be later than the
        next measurement's and the real answer to that would be refused.
        """
        if self.is_answered(stamp_ns):
            self.duplicates += 1
            return False
        sent_ns = self._sent_wall_ns.get(stamp_ns)
        if sent_ns is None:
            return True
        self.latency.add(arrival_ns - sent_ns)
        if stamp_ns != self.last_sent_stamp_ns:
            self.late += 1  # a newer measurement was already out
        self.last_answered_stamp_ns, self.last_answer_wall_ns = stamp_ns, arrival_ns
        return True

    def command_age_s(self, now_ns: int) -> float:
        """Seconds since the last accepted command (inf if none yet)."""
        return float("inf") if self.last_answer_wall_ns is None else (now_ns - self.last_answer_wall_ns) * 1e-9

    def summary(self) -> dict:
        """Counters and latency / jitter / turnaround percentiles in ms, for diagnostics."""
        out = {
            "measurements": self.measurements, "commands": self.latency.count, "late": self.late,
            "duplicates": self.duplicates, "deadline_misses": self.deadline_misses,
            "command_timeouts": self.command_timeouts, "skipped_reports": self.skipped_reports,
        }
        for name, distribution in (("latency", self.latency), ("jitter", self.jitter),
                                   ("turnaround", self.turnaround)):
            if distribution.count:
                p50, p99 = distribution.percentiles_ns((50, 99))
                out[f"{name}_p50_ms"] = p50 * 1e-6
                out[f"{name}_p99_ms"] = p99 * 1e-6
                largest = distribution.max_abs_ns if name == "jitter" else distribution.max_ns
                out[f"{name}_max_ms"] = largest * 1e-6
        return out
