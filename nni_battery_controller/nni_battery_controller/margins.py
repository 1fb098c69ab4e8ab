"""Stability margins: the searches for the critical clearing time and the delay margin, and the equal-area closed form.

Each search is given the runs as a callable (does the run with this clearing
time, or with this fixed measurement-to-command delay, stay in synchronism?):
:func:`critical_clearing_time` bisects the clearing time of the SMIB's fault;
:func:`delay_margins` scans the delay, then bisects, for many battery limits
at once (the SMIB and the network study both search with it).
:func:`equal_area_clearing_time_s` is the SMIB's critical clearing time in
closed form where the equal-area criterion gives one.

Pure python: no ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from nni_battery_controller.verdicts import INSTANT_DECIMALS
from nni_plant_sim.model import SmibParams

#: Precision of the critical clearing time search, s.
CCT_TOLERANCE_S = 1e-3


@dataclass(frozen=True)
class ClearingTime:
    """Critical clearing time of a transfer-limit fault for one b, bracketed by bisection.

    The run stays in synchronism (over ``duration_s``) when the fault clears at
    ``in_sync_s`` and slips when it clears at ``slips_s``; ``slips_s - in_sync_s``
    <= the tolerance. ``cct_s`` is ``in_sync_s``, the longest clearing time
    shown to keep synchronism. ``slips_s`` is None (and cct_s the search's
    upper end) when no clearing time up to that end slipped.
    """

    b: float
    cct_s: float
    in_sync_s: float
    slips_s: float | None
    runs: int

    def to_json(self) -> dict:
        """JSON-ready dict; b = inf is written as the string "inf"."""
        return {"b": "inf" if math.isinf(self.b) else self.b, "cct_s": self.cct_s,
                "bracket_s": [self.in_sync_s, self.slips_s], "runs": self.runs}


def critical_clearing_time(in_sync, b: float, upper_s: float, tolerance_s: float = CCT_TOLERANCE_S) -> ClearingTime:
    """Bisection for the longest clearing time ``t`` with ``in_sync(t)`` true.

    ``in_sync(t)`` runs the fault cleared at ``t`` s and says whether the
    machine stayed in synchronism. The bracket starts at [0, tolerance] (no
    fault keeps the equilibrium) and doubles its upper end until a run slips
    (or ``upper_s`` is reached), then halves to ``tolerance_s``. Instants are
    rounded to 1 ns.
    """
    low, high, runs = 0.0, tolerance_s, 0
    while True:
        runs += 1
        if not in_sync(high):
            break
        if high >= upper_s:
            return ClearingTime(b, round(high, INSTANT_DECIMALS), round(high, INSTANT_DECIMALS), None, runs)
        low, high = high, min(2.0 * high, upper_s)
    while high - low > tolerance_s:
        mid = 0.5 * (low + high)
        runs += 1
        low, high = (mid, high) if in_sync(mid) else (low, mid)
    low, high = round(low, INSTANT_DECIMALS), round(high, INSTANT_DECIMALS)
    return ClearingTime(b, low, low, high, runs)


#: Precision of the delay margin search, s.
DELAY_MARGIN_TOLERANCE_S = 1e-3


@dataclass(frozen=True)
class DelayMargin:
    """The delay margin of one b: the largest fixed measurement-to-command delay shown to keep synchronism.

    ``margin_s``: the longest delay tried that kept the run in synchronism,
    and no shorter one tried slipped; ``slips_s``: the shortest that slipped
    (``slips_s - margin_s`` <= the tolerance). ``margin_s`` None: the run slips
    even without delay (no margin at all). ``slips_s`` None: no delay tried up
    to ``upper_s`` slipped ("no margin found up to upper_s"; ``margin_s`` is
    then the last delay tried, a lower bound, not the margin, and the JSON's
    ``delay_margin_s`` is null).
    """

    b: float
    margin_s: float | None
    slips_s: float | None
    upper_s: float
    runs: int

    def to_json(self) -> dict:
        """JSON-ready dict; b = inf is written as the string "inf"."""
        found = self.slips_s is not None
        return {"b": "inf" if math.isinf(self.b) else self.b, "delay_margin_s": self.margin_s if found else None,
                "bracket_s": [self.margin_s, self.slips_s], "slip_found": found,
                "in_synchronism_up_to_s": self.margin_s, "searched_up_to_s": self.upper_s, "runs": self.runs}

    def text(self) -> str:
        """The table cell: the margin, or what the search found instead."""
        if self.margin_s is None:
            return "none: out of synchronism even without delay"
        if self.slips_s is None:
            return f"no margin found up to {self.upper_s:g} s (in synchronism at every delay tried)"
        return f"{self.margin_s * 1e3:.1f} ms (slips at {self.slips_s * 1e3:.1f} ms)"


#: Step of the delay margin's scan when not given, s.
DELAY_SCAN_STEP_S = 0.05


def delay_margins(in_sync, limits, scan_step_s: float, upper_s: float,
                  tolerance_s: float = DELAY_MARGIN_TOLERANCE_S) -> list[DelayMargin]:
    """The first loss of synchronism as the delay grows, per battery limit: scan, then bisect.

    ``in_sync(delay_s, indices)`` runs the loop with a fixed delay of
    ``delay_s`` s for the limits ``limits[i]``, i in ``indices`` (one batch),
    and says for each whether it stayed in synchronism. Delay 0 first (a run
    that slips there has no margin), then d = j ``scan_step_s`` for j = 1, 2,
    ... up to ``upper_s`` until each limit's run slips, then bisection of
    [last in sync, first slip] to ``tolerance_s``. As for any such search,
    synchronism is assumed monotone between the delays tried (it need not be:
    a finer scan can find an earlier loss). Delays rounded to 1 ns.
    """
    n = len(limits)
    runs = [1] * n
    at_zero = list(in_sync(0.0, list(range(n))))
    low, high = [0.0] * n, [None if ok else 0.0 for ok in at_zero]
    j = 1
    while (delay := round(j * scan_step_s, INSTANT_DECIMALS)) <= upper_s + 1e-12:
        undecided = [i for i in range(n) if high[i] is None]
        if not undecided:
            break
        for i, ok in zip(undecided, in_sync(delay, undecided)):
            runs[i] += 1
            low[i], high[i] = (delay, None) if ok else (low[i], delay)
        j += 1
    for i in range(n):
        while at_zero[i] and high[i] is not None and high[i] - low[i] > tolerance_s:
            mid = round(0.5 * (low[i] + high[i]), INSTANT_DECIMALS)
            runs[i] += 1
            low[i], high[i] = (mid, high[i]) if in_sync(mid, [i])[0] else (low[i], mid)
    return [DelayMargin(limits[i], low[i] if at_zero[i] else None, high[i], upper_s, runs[i]) for i in range(n)]


def equal_area_clearing_time_s(plant: SmibParams) -> float:
    """Critical clearing time of a bolted fault (P_max = 0 while it lasts), no battery, D = 0.

    During the fault M delta'' = P_M, so delta - delta_bar = P_M t^2 / (2 M).
    Equal areas of acceleration (delta_bar to delta_cr, P_M) and deceleration
    (delta_cr to the unstable equilibrium pi - delta_bar, P_max sin delta - P_M)
    give cos(delta_cr) = (pi - 2 delta_bar) sin(delta_bar) - cos(delta_bar), and
    t_cr = sqrt(2 M (delta_cr - delta_bar) / P_M). Paper case: 0.1127 s.
    """
    delta_bar = plant.delta_bar_rad
    delta_cr = math.acos((math.pi - 2.0 * delta_bar) * math.sin(delta_bar) - math.cos(delta_bar))
    return math.sqrt(2.0 * plant.inertia_m * (delta_cr - delta_bar) / plant.p_mech_pu)
