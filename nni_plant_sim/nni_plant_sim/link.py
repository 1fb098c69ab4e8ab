"""The communication link between a generator's PMU and its battery: delay, jitter and loss, seeded.

A wide-area link is not localhost. This model sits, at the plant, between a
battery command's arrival (after the plant's command path has admitted it)
and the instant it takes effect, the same way in the offline sampled-data
simulations (:mod:`nni_battery_controller.simulate`,
:mod:`nni_battery_controller.network_sim`) and in both time modes of the
plant's reporting core (:mod:`nni_plant_sim.reporting`):

* the answer to measurement k (taken at t_k) of generator i takes effect at
  t_k + d_k, d_k = delay_i + jitter_i u_k, u_k uniform on [0, 1), rounded to
  1 ns (the resolution of ROS time); or it is **lost** with probability
  loss_i, and the command in force stays (lockstep and offline; realtime also
  keeps the plant's command timeout: a battery that hears nothing for
  ``command_timeout_s`` decays to zero, a lost answer being one it never heard);
* u_k and the loss draw depend only on (seed, generator, k): one
  :class:`numpy.random.Generator` seeded with that triple, so that lockstep,
  realtime and offline draw the same values whatever the order they ask in;
* an answer that would take effect after the answer to a later measurement
  already did (jitter reordering them) is superseded: it never takes effect.

:class:`DelayLine` holds the answers on their way and cuts an integration
interval at the instants they take effect; both the plant and the offline
simulations integrate through it, piece by piece, with the very same cuts
and powers, so that a lockstep run equals the offline one to rounding.
Pure python and numpy: no ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

#: Decimal places the drawn delays are rounded to (1 ns).
DELAY_DECIMALS = 9


def _per_generator(value, name: str, low: float, high: float) -> tuple[float, ...]:
    values = tuple(float(v) for v in np.atleast_1d(np.asarray(value, dtype=float)))
    for v in values:
        if not low <= v <= high:
            raise ValueError(f"link {name} must be within [{low:g}, {high:g}], got {v!r}")
    return values


@dataclass(frozen=True)
class Link:
    """Per generator: fixed delay (s), jitter (s, the width of a uniform extra delay), loss probability; one seed.

    Each of ``delay_s``, ``jitter_s``, ``loss`` is one value (every
    generator) or one per generator. The default is no link: every answer
    takes effect at its measurement's instant, as without the model.
    """

    delay_s: tuple | float = 0.0
    jitter_s: tuple | float = 0.0
    loss: tuple | float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "delay_s", _per_generator(self.delay_s, "delay (s)", 0.0, 1e3))
        object.__setattr__(self, "jitter_s", _per_generator(self.jitter_s, "jitter (s)", 0.0, 1e3))
        object.__setattr__(self, "loss", _per_generator(self.loss, "loss probability", 0.0, 1.0))
        if not (isinstance(self.seed, (int, np.integer)) and 0 <= self.seed < 2**63):
            raise ValueError(f"link seed must be an integer >= 0, got {self.seed!r}")

    @property
    def active(self) -> bool:
        """False for no link at all (no delay, jitter or loss anywhere): answers take effect at once."""
        return any(self.delay_s) or any(self.jitter_s) or any(self.loss)

    def _of(self, values: tuple, generator: int) -> float:
        return values[0] if len(values) == 1 else values[generator]

    def with_delay(self, delay_s) -> "Link":
        """The same link with another fixed delay (the delay-margin search)."""
        return Link(delay_s, self.jitter_s, self.loss, self.seed)

    @cached_property
    def _fixed_delays(self) -> tuple | None:
        """Each generator's delay (s, rounded as :meth:`draw` rounds), when no generator has jitter or loss; else None.

        What :meth:`draw` returns then, looked up: it runs once per answer, on the lockstep plant's
        critical path (1.2 us drawn, 0.2 looked up).
        """
        if any(self.jitter_s) or any(self.loss):
            return None
        return tuple(round(delay, DELAY_DECIMALS) for delay in self.delay_s)

    def draw(self, generator: int, k: int) -> float | None:
        """Delay (s, rounded to 1 ns) of the answer to measurement ``k`` of ``generator`` (0-based); None: lost."""
        fixed = self._fixed_delays
        if fixed is not None:
            return fixed[0] if len(fixed) == 1 else fixed[generator]
        delay, jitter, loss = (self._of(v, generator) for v in (self.delay_s, self.jitter_s, self.loss))
        if not (jitter or loss):
            return round(delay, DELAY_DECIMALS)
        u_loss, u_jitter = np.random.default_rng((self.seed, generator, k)).random(2)
        if u_loss < loss:
            return None
        return round(delay + jitter * float(u_jitter), DELAY_DECIMALS)

    def describe(self) -> str:
        """One line for a table's header: ``link: delay 100 ms, jitter 20 ms (uniform), loss 0.05, seed 0``."""
        def text(values, scale=1.0):
            return "/".join(f"{v * scale:g}" for v in values)

        return (f"link: delay {text(self.delay_s, 1e3)} ms, jitter {text(self.jitter_s, 1e3)} ms (uniform), "
                f"loss {text(self.loss)}, seed {self.seed} (a lost answer leaves the command in force)")

    def to_json(self) -> dict:
        def one(values):
            return values[0] if len(values) == 1 else list(values)

        return {"delay_s": one(self.delay_s), "jitter_s": one(self.jitter_s), "loss": one(self.loss),
                "seed": int(self.seed), "jitter_distribution": "uniform [0, jitter_s)",
                "lost_answer": "the command in force stays"}


NO_LINK = Link()


class DelayLine:
    """The answers of ``n`` generators on their way through ``link``, and the powers in force.

    ``powers``: the power in force at each generator (floats, or arrays of
    one shape for a batch of runs). :meth:`send` puts the answer to
    measurement k on its way; :meth:`pieces` cuts an interval at the instants
    answers take effect and puts them in force there. ``on_effect(generator,
    power)``, if given, is told each time a power is put in force. Times are
    seconds on the run's clock (simulated time, or the reporting grid's in
    realtime). ``store``: the batteries' charge (:class:`nni_plant_sim.battery.EnergyStore`,
    float powers only): the pieces are cut where one runs empty or full as well,
    and :meth:`applied_powers` is what they give over each piece.
    """

    def __init__(self, link: Link, powers, on_effect=None, store=None):
        self.link = link
        self.powers = list(powers)
        self.store = store
        self._on_effect = on_effect
        self._in_force_k = [-1] * len(self.powers)  # the measurement whose answer is in force
        self._pending: list[tuple[float, int, int, object]] = []  # (effect s, generator, k, power), by effect
        self.lost = [0] * len(self.powers)
        self.superseded = [0] * len(self.powers)

    def send(self, generator: int, k: int, t_k: float, power, now_s: float) -> float | None:
        """The answer to measurement ``k`` (taken at ``t_k`` s), at ``now_s``: its effect instant, or None (lost).

        An answer due at or before ``now_s`` takes effect at once (without a
        link: always, at its measurement's instant).
        """
        delay = self.link.draw(generator, k)
        if delay is None:
            self.lost[generator] += 1
            return None
        effect = t_k + delay
        if effect <= now_s:
            self._take_effect(generator, k, power)
        else:
            self._pending.append((effect, generator, k, power))
            self._pending.sort(key=lambda item: item[0])
        return effect

    def force(self, generator: int, k: int, power) -> None:
        """Put ``power`` in force now (a timeout's zero); answers on their way to measurements <= ``k`` are superseded."""
        self._in_force_k[generator] = max(self._in_force_k[generator], k)
        self._put(generator, power)

    def _take_effect(self, generator: int, k: int, power) -> None:
        if k <= self._in_force_k[generator]:
            self.superseded[generator] += 1
            return
        self._in_force_k[generator] = k
        self._put(generator, power)

    def _put(self, generator: int, power) -> None:
        self.powers[generator] = power
        if self._on_effect is not None:
            self._on_effect(generator, power)

    def snapshot(self):
        """What :meth:`restore` takes back (a realtime reporter's redo of a piece integrated ahead), the store's charge too."""
        charge = None if self.store is None else self.store.snapshot()
        return list(self._pending), list(self.powers), list(self._in_force_k), list(self.superseded), charge

    def restore(self, snapshot) -> None:
        *parts, charge = snapshot
        pending, powers, in_force_k, self.superseded = (list(part) for part in parts)
        self._pending, self._in_force_k = pending, in_force_k
        if charge is not None:
            self.store.restore(charge)
        for generator, power in enumerate(powers):
            self._put(generator, power)

    def narrow(self, keep) -> None:
        """Keep only the runs ``keep`` (a mask or indices) of a batch: every power is an array over runs."""
        self.powers = [power[keep] for power in self.powers]
        self._pending = [(effect, generator, k, power[keep]) for effect, generator, k, power in self._pending]

    def pieces(self, t0_s: float, t1_s: float):
        """Yield the ``(start, stop)`` pieces of [t0, t1], :attr:`powers` in force over each.

        An answer due in (t0, t1] takes effect when the piece ending at its
        instant is done (its instant is a cut); one due at or before t0 takes
        effect before the first piece. Nothing due inside: one piece, (t0, t1).
        """
        start = t0_s
        self._apply_due(start)
        while self._pending and self._pending[0][0] < t1_s:
            stop = self._pending[0][0]
            yield from self._held(start, stop)
            start = stop
            self._apply_due(start)
        if t1_s > start:
            yield from self._held(start, t1_s)
        self._apply_due(t1_s)

    def applied_powers(self) -> list:
        """The powers in force as the batteries give them (without a store: :attr:`powers`)."""
        return self.powers if self.store is None else self.store.applied(self.powers)

    def _held(self, start: float, stop: float):
        """[start, stop] with no answer due inside, cut where a battery of the store runs empty or full."""
        if self.store is None:
            yield start, stop
            return
        while True:
            powers = self.store.applied(self.powers)
            left, which = self.store.time_to_bound(powers)
            end, bound = (start + left, which) if start + left <= stop else (stop, None)
            yield start, end
            self.store.hold(powers, start, end, bound)
            if end >= stop:
                return
            start = end

    def _apply_due(self, t_s: float) -> None:
        while self._pending and self._pending[0][0] <= t_s:
            _, generator, k, power = self._pending.pop(0)
            self._take_effect(generator, k, power)


def integrate_through(line: DelayLine, integrate, t0_s: float, t1_s: float, state):
    """``state`` integrated over [t0, t1] piecewise, each piece with the powers in force over it.

    ``integrate(start, stop, state, powers)`` (``powers``: the line's list,
    one entry per generator) does one piece; the plant's reporting core and
    the offline simulations integrate through this one function.
    """
    for start, stop in line.pieces(t0_s, t1_s):
        state = integrate(start, stop, state, line.applied_powers())
    return state
