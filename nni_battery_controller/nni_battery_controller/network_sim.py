"""A battery law (:mod:`.laws`; the saturated H3-hat by default) at every generator of a network, sampled at the PMU rate, offline.

Per generator i, with local information only (its own angle and the electrical
power a PMU at its terminals measures):

    g_i   = P_e,i(delta_bar) - P_e,i(measured)
    w_i   = x3_i - L_i d_i - g_i,      P_ST,i = sat_b_i(w_i)
    x3_i  advanced exactly over the period for the mode held (as law.SampledController)

``d_i`` is the angle deviation against the reference chosen: ``pmu`` (the PMU's
own angle against the nominal-frequency reference, ``delta_i - delta_bar_i``)
or ``coi`` (relative to the centre of inertia, which needs every generator's
angle: a distributed controller). Gains and limits are given per generator in
pu of the machine's rating and converted to the system base.

Many runs of one case (different b, different clearing times) share one
vectorised integration: states have shape (2, N, R). Pure numpy: no ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nni_battery_controller.law import ControllerParams, last_saturated
from nni_battery_controller.laws import DEFAULT_LAW, SPEED_LAWS, ArrayLaw, Law
from nni_plant_sim.battery import EnergyStore
from nni_plant_sim.integrators import advance
from nni_plant_sim.link import NO_LINK, DelayLine, Link, integrate_through
from nni_plant_sim.network import Network, electrical_power

ANGLE_REFERENCES = ("pmu", "coi")
#: Band (rad) around its final value within which a COI-relative angle counts as settled.
SETTLE_BAND_RAD = 0.02
POLE_SLIP_RAD = math.pi


def per_generator(value, n: int, name: str) -> np.ndarray:
    """One value for every generator, or exactly n values; ValueError naming the option otherwise."""
    values = np.atleast_1d(np.asarray(value, dtype=float))
    if values.size == 1:
        return np.full(n, float(values[0]))
    if values.size != n:
        raise ValueError(f"{name}: give one value or one per generator ({n}), got {values.size}")
    return values


@dataclass(frozen=True)
class NetworkLaw:
    """One law (:mod:`.laws`) at each generator, its gains in pu of the machine's rating.

    The NNI laws' gains (tau, K, L, alpha) may differ per generator, ``K_i < L_i``
    checked for each (a violation names the generator and the condition); a
    speed law's ``gains`` (:data:`.laws.GAINS`) are every generator's.
    """

    net: Network
    tau_s: np.ndarray
    gain_k: np.ndarray
    gain_l: np.ndarray
    alpha: np.ndarray
    reference: str = "pmu"
    name: str = DEFAULT_LAW
    gains: object = None

    def __post_init__(self) -> None:
        if self.reference not in ANGLE_REFERENCES:
            raise ValueError(f"angle reference must be one of {', '.join(ANGLE_REFERENCES)}, got {self.reference!r}")
        object.__setattr__(self, "gains", Law(self.name, gains=self.gains).gains)
        for i, name in enumerate(self.net.names):
            try:
                ControllerParams(float(self.tau_s[i]), float(self.gain_k[i]), float(self.gain_l[i]),
                                 float(self.alpha[i]))
            except ValueError as error:
                raise ValueError(f"generator {name}: {error}") from None

    @classmethod
    def uniform(cls, net: Network, tau_s, gain_k, gain_l, alpha, reference: str = "pmu", name: str = DEFAULT_LAW,
                gains=None) -> "NetworkLaw":
        """From one value or one per generator of each NNI gain; ``name`` and ``gains``: the law (default nni)."""
        n = net.size
        return cls(net, per_generator(tau_s, n, "tau"), per_generator(gain_k, n, "K"), per_generator(gain_l, n, "L"),
                   per_generator(alpha, n, "alpha"), reference, name, gains)

    @property
    def uses_speed(self) -> bool:
        return self.name in SPEED_LAWS

    def laws(self) -> tuple:
        """The :class:`.laws.Law` of each generator (the battery limit is the run's, not here)."""
        return tuple(Law(self.name, ControllerParams(float(self.tau_s[i]), float(self.gain_k[i]),
                                                     float(self.gain_l[i]), float(self.alpha[i])), self.gains)
                     for i in range(self.net.size))

    def describe(self) -> str:
        """The law and its gains in one line (the NNI gains: the first generator's, and "per generator" if they differ)."""
        text = self.laws()[0].describe()
        if not self.uses_speed and any(np.ptp(v) > 0 for v in (self.tau_s, self.gain_k, self.gain_l, self.alpha)):
            text += " (per generator)"
        return text

    def angle_dev(self, delta_rad):
        """The controllers' input d_i for angles of shape (N,) or (N, R)."""
        column = (slice(None),) + (None,) * (np.ndim(delta_rad) - 1)
        dev = delta_rad - self.net.delta_bar_rad[column]
        if self.reference == "coi":
            dev = dev - self.net.coi(dev)
        return dev

    def speed_dev(self, speed_rad_s):
        """The speed laws' input: the speed deviation, against the centre of inertia's for reference coi."""
        if self.reference == "coi":
            return speed_rad_s - self.net.coi(speed_rad_s)
        return speed_rad_s


@dataclass
class NetworkController:
    """The law at every generator for R runs at once: one call per PMU sample.

    ``limits_pu`` (shape (N, R) or broadcastable) are the battery limits b_i on
    the system base. The update is :class:`.laws.ArrayLaw`, the SMIB's
    SampledLaw's formulas on arrays (tests check both agree step for step).
    ``state``: the law's state to start from (None: the pre-fault steady state).
    """

    law: NetworkLaw
    period_s: float
    limits_pu: np.ndarray
    state: np.ndarray | None = None

    def __post_init__(self) -> None:
        net = self.law.net
        if not (math.isfinite(self.period_s) and self.period_s > 0):
            raise ValueError(f"sampling period must be finite and positive, got {self.period_s}")
        self.limits_pu = np.asarray(self.limits_pu, dtype=float)
        self._array = ArrayLaw(self.law.laws(), self.period_s, self.limits_pu, 2.0 * math.pi * net.f0_hz,
                               net.mbase_mva / net.base_mva, self.state)

    @property
    def x3(self) -> np.ndarray:
        return self._array.x3

    def narrowed(self, keep) -> "NetworkController":
        """The same controllers for the runs ``keep`` only, their states kept."""
        return NetworkController(self.law, self.period_s, self.limits_pu[:, keep], self._array.state[..., keep])

    def step(self, delta_rad: np.ndarray, p_electrical_pu: np.ndarray, speed_rad_s: np.ndarray | None = None):
        """Answer one sample of angles, measured electrical powers and speeds, shape (N, R) each.

        Returns ``(P_ST, demand, saturated)`` (system base) and advances the state. The speed is
        needed by the speed laws only.
        """
        angle_dev = self.law.angle_dev(delta_rad)
        restoring = self.law.net.p_mech_pu[:, None] - p_electrical_pu
        speed = None if speed_rad_s is None else self.law.speed_dev(speed_rad_s)
        if speed is None and self.law.uses_speed:
            raise ValueError(f"law {self.law.name} needs the measured speeds")
        return self._array.step(angle_dev, speed, restoring)


@dataclass(frozen=True)
class NetworkTrajectory:
    """Samples t_0..t_n of R runs of one network: angles, speeds (n+1, N, R); P_ST, w, saturated likewise."""

    net: Network
    t_s: np.ndarray
    delta_rad: np.ndarray
    speed_rad_s: np.ndarray
    battery_power_pu: np.ndarray
    w_pu: np.ndarray
    saturated: np.ndarray
    limits_pu: np.ndarray
    #: A battery of finite energy (one run): each generator's charge at the end, pu s of its rating from empty, and
    #: when each first ran empty and full (None: never); None without an energy limit.
    charge_pu_s: tuple | None = None
    empty_at_s: tuple | None = None
    full_at_s: tuple | None = None

    def coi_angles(self) -> np.ndarray:
        """Angles relative to the centre of inertia, (n+1, N, R)."""
        weights = self.net.inertia_m / self.net.inertia_m.sum()
        return self.delta_rad - np.einsum("i,tir->tr", weights, self.delta_rad)[:, None, :]


def simulate_network(net: Network, law: NetworkLaw, scenario, limits_pu_mbase, duration_s: float, rate_hz: float,
                     max_step_s: float = 1e-3, drop_lost_runs: bool = False, link: Link = NO_LINK,
                     battery_energy_pu_s=math.inf) -> NetworkTrajectory:
    """R runs of the sampled-data closed loop; run r has battery limits ``limits_pu_mbase[r]`` (pu machine base).

    ``limits_pu_mbase`` is a sequence of R entries, each one value (every
    generator) or N values; ``inf`` unsaturated, 0 no battery. A scenario with
    an array of clearing times runs one clearing time per run (same R).
    At each sample t_k every controller reads its angle and measured electrical
    power, its battery power is held over [t_k, t_k+1), and the network is
    integrated by :func:`nni_plant_sim.integrators.advance` (the plant node's RK4).

    ``drop_lost_runs``: a run stops at the first sample where a pair of its
    generators is more than 180 degrees apart (its later samples are NaN), so
    that a batch of candidate clearing times spends nothing on decided runs.

    ``link``: generator i's answer to sample k takes effect at t_k + d_ik or is
    lost (its command in force stays), the same draws for every run of the
    batch; the network is integrated piecewise between those instants, as the
    network plant's reporting core does. ``battery_power_pu`` is then the
    power in force at each sample.

    ``battery_energy_pu_s`` (one value or N, pu s of each machine's rating; finite: one run only): each battery
    starts at half charge with that much to deliver and as much room to absorb, and gives nothing once empty (or
    takes nothing once full), through the plant's :class:`~nni_plant_sim.battery.EnergyStore` on the system base;
    ``battery_power_pu`` is then what each battery gives.
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"controller rate must be finite and positive, got {rate_hz}")
    limits = np.column_stack([net.pu_of_machine(per_generator(b, net.size, "b")) for b in limits_pu_mbase])
    if np.any(limits < 0) or np.any(np.isnan(limits)):
        raise ValueError("battery limits must be >= 0")
    runs = limits.shape[1]
    period = 1.0 / rate_hz
    n = int(round(duration_s * rate_hz))
    t = np.arange(n + 1) * period
    x = scenario.initial_state(net)
    if x.ndim == 2:  # one state for every run; else (2, N, R): each run its own (InitialStates)
        x = np.repeat(x[:, :, None], runs, axis=2)
    elif x.shape[2] != runs:
        raise ValueError(f"{x.shape[2]} initial states for {runs} runs")
    controller = NetworkController(law, period, limits)
    shape = (n + 1, net.size, runs)
    delta, speed, power, w, saturated = (np.full(shape, np.nan) for _ in range(5))
    active = np.arange(runs)
    energies = per_generator(battery_energy_pu_s, net.size, "battery energy")
    store = None
    if np.any(np.isfinite(energies)):
        if runs != 1:
            raise ValueError(f"a battery of finite energy takes one run at a time, got {runs}")
        store = EnergyStore(list(net.pu_of_machine(energies)))  # the powers on the line are on the system base
    line = DelayLine(link, [0.0] * net.size if store is not None else list(np.zeros((net.size, runs))), store=store)

    def piece(start, stop, x, powers):
        powers = np.array(powers)
        return advance(start, stop, x, powers if store is None else powers[:, None], net, scenario, max_step_s)

    for k in range(n + 1):
        measured = electrical_power(x[0], scenario.network(t[k], net)[1])
        delta[k][:, active], speed[k][:, active] = x
        step = controller.step(x[0], measured, x[1])
        for i in range(net.size):
            line.send(i, k, float(t[k]), step[0][i] if store is None else float(step[0][i][0]), float(t[k]))
        power[k][:, active] = np.array(line.applied_powers()).reshape(net.size, -1)  # without a store: in force
        w[k][:, active], saturated[k][:, active] = step[1], step[2]
        if drop_lost_runs and np.any(lost := angle_spread(x[0][None])[0] > POLE_SLIP_RAD):
            keep = ~lost
            if not keep.any():  # every run decided (a scenario narrowed to none is no scenario)
                break
            active, x = active[keep], x[:, :, keep]
            line.narrow(keep)
            controller = controller.narrowed(keep)
            scenario = scenario.narrowed(keep)
        if k < n:
            x = integrate_through(line, piece, float(t[k]), float(t[k + 1]), x)
    if store is None:
        return NetworkTrajectory(net, t, delta, speed, power, w, saturated == 1.0, limits)
    scale = net.pu_of_machine(np.ones(net.size))
    return NetworkTrajectory(net, t, delta, speed, power, w, saturated == 1.0, limits,
                             tuple(float(c) for c in np.asarray(store.charge_pu_s) / scale),
                             tuple(store.empty_at_s), tuple(store.full_at_s))


@dataclass(frozen=True)
class GeneratorOutcome:
    """One generator in one run. Powers in pu of its rating and in MW."""

    name: str
    in_synchronism: bool
    settled: bool
    settling_time_s: float | None
    max_abs_battery_power_pu: float
    max_abs_battery_power_mw: float
    limit_pu: float
    last_saturated_s: float | None


@dataclass(frozen=True)
class NetworkOutcome:
    """One run: the system verdict and one :class:`GeneratorOutcome` per generator.

    in_synchronism: no pair of generators ever more than 180 degrees apart
    (sampled at the PMU instants); pole_slip_s: the first sample where a pair
    was; settled: every generator's COI-relative angle within SETTLE_BAND_RAD of
    its final value over the last second; stable: both. final_coi_frequency_hz:
    the centre of inertia's frequency deviation at the end (without governors
    nothing restores it; the COI reference does not see it).
    """

    in_synchronism: bool
    pole_slip_s: float | None
    settled: bool
    stable: bool
    max_angle_spread_rad: float
    final_coi_frequency_hz: float
    generators: tuple

    def to_json(self) -> dict:
        """JSON-ready dict (inf limits as "inf")."""
        out = {k: v for k, v in self.__dict__.items() if k != "generators"}
        out["generators"] = [
            {**g.__dict__, "limit_pu": "inf" if math.isinf(g.limit_pu) else g.limit_pu} for g in self.generators]
        return out


def angle_spread(delta_rad: np.ndarray) -> np.ndarray:
    """Largest pairwise angle difference max_i delta_i - min_i delta_i over generators (axis 1)."""
    return delta_rad.max(axis=1) - delta_rad.min(axis=1)


def network_verdict(outcome) -> str:
    """``in synchronism, settled`` / ``..., not settled`` / ``LOST SYNCHRONISM at T s, ...`` (as a run's table)."""
    return (("in synchronism" if outcome.in_synchronism else f"LOST SYNCHRONISM at {outcome.pole_slip_s:.2f} s")
            + (", settled" if outcome.settled else ", not settled"))


def assess_network(traj: NetworkTrajectory, settle_band_rad: float = SETTLE_BAND_RAD) -> list[NetworkOutcome]:
    """Per run: synchronism (pairwise criterion), settling, battery peaks and the last saturated instant."""
    net, t = traj.net, traj.t_s
    spread = angle_spread(traj.delta_rad)
    relative = traj.coi_angles()
    off = np.abs(relative - relative[-1]) > settle_band_rad
    last_second = t >= t[-1] - 1.0
    outcomes = []
    for r in range(traj.delta_rad.shape[2]):
        slipped = np.flatnonzero(spread[:, r] > POLE_SLIP_RAD)
        in_sync = slipped.size == 0
        generators = []
        for i, name in enumerate(net.names):
            pairwise = np.abs(traj.delta_rad[:, i, r][:, None] - traj.delta_rad[:, :, r]).max()
            outside = np.flatnonzero(off[:, i, r])
            settled = bool(pairwise <= POLE_SLIP_RAD and not off[last_second, i, r].any())
            settle_time = 0.0 if outside.size == 0 else (float(t[outside[-1] + 1]) if outside[-1] + 1 < t.size
                                                         else None)
            sat_times = t[traj.saturated[:, i, r]]
            scale = net.base_mva / net.mbase_mva[i]
            peak = float(np.max(np.abs(traj.battery_power_pu[:, i, r])))
            generators.append(GeneratorOutcome(
                name, bool(pairwise <= POLE_SLIP_RAD), settled, settle_time if settled else None, peak * scale,
                peak * net.base_mva, float(traj.limits_pu[i, r] * scale),
                last_saturated(sat_times, traj.limits_pu[i, r])))
        settled_all = all(g.settled for g in generators)
        coi_speed = float(net.coi(traj.speed_rad_s[-1, :, r]))
        outcomes.append(NetworkOutcome(in_sync, None if in_sync else float(t[slipped[0]]), settled_all,
                                       in_sync and settled_all, float(spread[:, r].max()),
                                       coi_speed / (2.0 * math.pi), tuple(generators)))
    return outcomes


def critical_clearing_times(net: Network, law: NetworkLaw, make_fault, limits_pu_mbase, duration_s: float,
                            rate_hz: float, high_s: float = 1.0, resolution_s: float = 1e-3, points: int = 31,
                            max_step_s: float = 1e-3, link: Link = NO_LINK):
    """Critical clearing time per battery limit: the longest clearing time (on a ``resolution_s`` grid) that stays in synchronism.

    ``make_fault(clearing_times)`` builds the fault for an array of clearing
    times. All limits and ``points`` candidate clearing times per limit run in
    one vectorised integration per round; each round narrows every bracket
    [stable, unstable] to one of ``points + 1`` parts, down to ``resolution_s``.
    The CCT is the first loss: a stable candidate beyond the shortest unstable
    one found is ignored (stability need not be monotone in the clearing time:
    with batteries it sometimes is not). Between candidates monotonicity is
    assumed, as any bisection does: a finer search (``points``) can find an
    earlier loss. ``link``: every run through it (:func:`simulate_network`).
    Returns per limit ``(cct_s or None, (stable_s, unstable_s), at_limit)``:
    ``None`` when even the shortest clearing time loses synchronism;
    ``at_limit`` when ``high_s`` still holds (the CCT is then at least high_s).
    """
    step = resolution_s
    lo = np.zeros(len(limits_pu_mbase), dtype=int)                 # known stable (0: no fault at all)
    hi = np.full(len(limits_pu_mbase), int(round(high_s / step)) + 1)  # known unstable (beyond the range)
    while np.any(hi - lo > 1):
        candidates, owners = [], []
        for j in range(len(limits_pu_mbase)):
            if hi[j] - lo[j] > 1:
                grid = np.unique(np.linspace(lo[j], hi[j], points + 2).round().astype(int)[1:-1])
                grid = grid[(grid > lo[j]) & (grid < hi[j])]
                candidates.extend(grid)
                owners.extend([j] * grid.size)
        candidates, owners = np.array(candidates), np.array(owners)
        traj = simulate_network(net, law, make_fault(candidates * step), [limits_pu_mbase[j] for j in owners],
                                duration_s, rate_hz, max_step_s, drop_lost_runs=True, link=link)
        stable = ~np.any(angle_spread(traj.delta_rad) > POLE_SLIP_RAD, axis=0)
        for j in np.unique(owners):
            mine = owners == j
            good, bad = candidates[mine & stable], candidates[mine & ~stable]
            hi[j] = min(hi[j], bad.min()) if bad.size else hi[j]
            good = good[good < hi[j]]
            lo[j] = max(lo[j], good.max()) if good.size else lo[j]
    top = int(round(high_s / step))
    return [(None if lo[j] == 0 else float(lo[j] * step), (float(lo[j] * step), float(hi[j] * step)), lo[j] >= top)
            for j in range(len(limits_pu_mbase))]
