"""A battery of finite energy: its state of charge, where the power flows (issue 32).

Each generator's battery starts at half charge with ``energy_pu_s`` to deliver and as much room to absorb
(pu s of the machine's rating: 1 pu s is the rating for one second). Delivering (P_ST > 0) drains it, absorbing
(P_ST < 0) charges it, both without losses; an empty battery delivers nothing and a full one absorbs nothing,
whatever it is asked for. :class:`nni_plant_sim.link.DelayLine` cuts an integration interval at the instant a
battery runs empty or full, so that the powers in force are constant over each piece and the charge is exact
(to rounding), in the offline simulations and (once the plant node takes it) in the plant alike.
``energy_pu_s = inf``: no energy limit, the model's default and the loop without it.

Pure python: no ROS import.
"""

from __future__ import annotations

import math


def battery_energy(value: float) -> float:
    """The energy a battery can deliver, pu s, checked: ValueError (one line) unless > 0 (``inf``: unlimited)."""
    value = float(value)
    if math.isnan(value) or value <= 0:
        raise ValueError(f"a battery's energy must be > 0 pu s (inf: unlimited), got {value!r}")
    return value


def charge_over(t_s, powers_pu, energy_pu_s: float) -> list[float]:
    """The charge (pu s from empty) at each instant of ``t_s`` of one battery of ``energy_pu_s``, from half charge,
    that gives ``powers_pu[k]`` from ``t_s[k]`` to ``t_s[k + 1]``: the plant's recorded states, each carrying the
    power the battery gives from that instant on (:meth:`EnergyStore.hold`, bounded at empty and full).

    Exact where the recorded powers held over each period, as in lockstep: a battery that ran empty inside a period
    ends it empty either way, and gives nothing after. In realtime a command applied inside a period is credited
    from the period's start, off by its latency times the step of the power."""
    store = EnergyStore([energy_pu_s])
    charges = [store.charge_pu_s[0]]
    for start, stop, power in zip(t_s[:-1], t_s[1:], powers_pu[:-1]):
        store.hold([float(power)], float(start), float(stop))
        charges.append(store.charge_pu_s[0])
    return charges


class EnergyStore:
    """The charge of each generator's battery, pu s from empty; each full at ``2 energy_pu_s``."""

    def __init__(self, energy_pu_s):
        self.energy_pu_s = [battery_energy(e) for e in energy_pu_s]
        self.charge_pu_s = list(self.energy_pu_s)
        self.empty_at_s: list[float | None] = [None] * len(self.energy_pu_s)
        self.full_at_s: list[float | None] = [None] * len(self.energy_pu_s)

    def snapshot(self) -> tuple:
        """What :meth:`restore` takes back: the charge, and when each ran empty and full."""
        return list(self.charge_pu_s), list(self.empty_at_s), list(self.full_at_s)

    def restore(self, snapshot) -> None:
        self.charge_pu_s, self.empty_at_s, self.full_at_s = (list(part) for part in snapshot)

    def applied(self, powers) -> list[float]:
        """The powers the batteries give when asked for ``powers``: none from an empty one, none into a full one."""
        return [0.0 if (p > 0 and charge <= 0.0) or (p < 0 and charge >= 2 * energy) else p
                for p, charge, energy in zip(powers, self.charge_pu_s, self.energy_pu_s)]

    def time_to_bound(self, powers) -> tuple[float, int | None]:
        """How long ``powers`` (as applied) can be held before a battery runs empty or full, and which one."""
        soonest, which = math.inf, None
        for i, (p, charge, energy) in enumerate(zip(powers, self.charge_pu_s, self.energy_pu_s)):
            left = charge / p if p > 0 else ((2 * energy - charge) / -p if p < 0 else math.inf)
            if left < soonest:
                soonest, which = left, i
        return soonest, which

    def hold(self, powers, start_s: float, stop_s: float, bound: int | None = None) -> None:
        """``powers`` (as applied) held over [start, stop]; ``bound``: the battery that reached its bound at stop."""
        for i, p in enumerate(powers):
            if p == 0.0 or math.isinf(self.energy_pu_s[i]):
                continue
            charge = self.charge_pu_s[i] - p * (stop_s - start_s)
            if i == bound:
                charge = 0.0 if p > 0 else 2 * self.energy_pu_s[i]
            self.charge_pu_s[i] = min(max(charge, 0.0), 2 * self.energy_pu_s[i])
            if self.charge_pu_s[i] == 0.0 and self.empty_at_s[i] is None:
                self.empty_at_s[i] = stop_s
            if self.charge_pu_s[i] == 2 * self.energy_pu_s[i] and self.full_at_s[i] is None:
                self.full_at_s[i] = stop_s
