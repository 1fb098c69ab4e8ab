"""Loop timing bookkeeping at the plant: latency, timer jitter, misses and drops.

Cheap and always on (a few list appends per sample); percentiles are computed
only when a summary is asked for (diagnostics, once a second). Pure python.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

#: How many recent samples remember their send time (answers to older ones are late anyway).
_REMEMBERED_SAMPLES = 256


class LoopStats:
    """Per-sample timing of the measurement -> command loop, seen from the plant.

    Latency of a sample: wall time from publishing its measurement (realtime:
    its stamp, the measurement instant) to the arrival of the command that
    answers it. A deadline miss: a reporting instant reached with the previous
    sample unanswered (lockstep: a timeout).
    """

    def __init__(self, period_s: float):
        self.period_s = period_s
        self.latencies_ns: list[int] = []
        self.jitter_ns: list[int] = []
        self._sent_wall_ns: OrderedDict[int, int] = OrderedDict()
        self.last_sent_stamp_ns: int | None = None
        self.last_sent_wall_ns: int | None = None
        self.last_answered_stamp_ns: int | None = None
        self.last_answer_wall_ns: int | None = None
        self.late = 0
        self.rejected = 0
        self.deadline_misses = 0
        self.command_timeouts = 0
        self.duplicates = 0

    def sent(self, stamp_ns: int, wall_ns: int) -> None:
        """A measurement with ``stamp_ns`` left the plant at ``wall_ns``."""
        self._sent_wall_ns[stamp_ns] = wall_ns
        if len(self._sent_wall_ns) > _REMEMBERED_SAMPLES:
            self._sent_wall_ns.popitem(last=False)
        self.last_sent_stamp_ns, self.last_sent_wall_ns = stamp_ns, wall_ns

    def tick(self, now_ns: int, ideal_ns: int) -> None:
        """A realtime reporting instant: record timer jitter; a miss if the last sample is unanswered."""
        self.jitter_ns.append(now_ns - ideal_ns)
        if self.last_sent_stamp_ns is not None and self.last_answered_stamp_ns != self.last_sent_stamp_ns:
            self.deadline_misses += 1

    def answered(self, stamp_ns: int, arrival_ns: int) -> bool:
        """A command answering ``stamp_ns`` arrived. False for a duplicate or out-of-order answer."""
        if self.last_answered_stamp_ns is not None and stamp_ns <= self.last_answered_stamp_ns:
            self.duplicates += 1
            return False
        sent_ns = self._sent_wall_ns.get(stamp_ns)
        if sent_ns is not None:
            self.latencies_ns.append(arrival_ns - sent_ns)
        if stamp_ns != self.last_sent_stamp_ns:
            self.late += 1  # a newer measurement was already out
        self.last_answered_stamp_ns, self.last_answer_wall_ns = stamp_ns, arrival_ns
        return True

    def command_age_s(self, now_ns: int) -> float:
        """Seconds since the last accepted command (inf if none yet)."""
        return float("inf") if self.last_answer_wall_ns is None else (now_ns - self.last_answer_wall_ns) * 1e-9

    def summary(self) -> dict:
        """Counters and latency/jitter percentiles in ms, for diagnostics."""
        out = {
            "commands": len(self.latencies_ns), "late": self.late, "rejected": self.rejected,
            "duplicates": self.duplicates, "deadline_misses": self.deadline_misses,
            "command_timeouts": self.command_timeouts,
        }
        for name, values in (("latency", self.latencies_ns), ("jitter", self.jitter_ns)):
            if values:
                ms = np.asarray(values, dtype=float) * 1e-6
                out[f"{name}_p50_ms"] = float(np.percentile(ms, 50))
                out[f"{name}_p99_ms"] = float(np.percentile(ms, 99))
                out[f"{name}_max_ms"] = float(np.max(np.abs(ms)) if name == "jitter" else np.max(ms))
        return out
