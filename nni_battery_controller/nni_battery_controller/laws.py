"""The battery laws: the saturated NNI law and the laws grid batteries run today, sampled at the PMU rate.

Five laws, each a pure core (no ROS import), each answering one measurement
per period with the battery power ``P_ST = sat_b(v)`` for a demand ``v`` (pu of
the machine's rating), ``b`` the battery limit:

``nni``
    the paper's saturated H3-hat (:mod:`.law`): ``v = w = x3 - L d - g``, x3
    switching to ``x3' = -(alpha/K) x3`` while ``|w| >= b``. The default.
``nni-unsaturated``
    the paper's H3: x3 always follows ``x3' = (K d - x3)/tau`` (it never knows
    the battery has a limit); its output is clipped at b, as the plant's rating
    clips it. At ``b = inf`` the two NNI laws are the same.
``droop``
    fast frequency response: ``v = -K_f dw``, ``dw = (omega - omega0)/omega0``
    the frequency deviation in pu.
``vsm``
    virtual inertia and damping: ``v = -(2 H_v s/(1 + s T_f) dw + D_v dw)``; the
    rate of change of frequency is the measurements' own, through a first-order
    filter (time constant T_f), as a device would compute it, not the model's.
``pss``
    a power system stabiliser of the IEEE 421.5 PSS1A structure on speed:
    ``v = -K_s [s T_w/(1 + s T_w)] [(1 + s T_1)/(1 + s T_2)] [(1 + s T_3)/(1 + s T_4)] dw``
    (its transducer filter and output limits omitted: the output limit is b).

The speed laws are linear filters of dw: each is a state space (A, B, C, D)
from dw to v, discretised exactly for the input held over the period (zero
order hold, the sampled NNI law's rule too): ``z+ = Ad z + Bd dw``, ``v = C z + D dw``.
Their state never depends on the output, so saturation winds nothing up.

:class:`Law` names a law with its gains and the battery limit (the NNI gains and
b live in :class:`~.law.ControllerParams`, as before); :meth:`Law.sampled` is
the law of one generator, Python floats on the controller's critical path;
:class:`ArrayLaw` the same laws on arrays (every generator of a network, many
runs at once), by the same formulas (tests check the two agree).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from nni_battery_controller.law import ControllerParams, SampledController, sampled_step

LAW_NAMES = ("nni", "nni-unsaturated", "droop", "vsm", "pss")
DEFAULT_LAW = "nni"
#: The laws that act on the measured speed (the others on the angle).
SPEED_LAWS = ("droop", "vsm", "pss")


def _positive(owner, *names) -> None:
    for name in names:
        value = getattr(owner, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and positive, got {value}")


def _non_negative(owner, *names) -> None:
    for name in names:
        value = getattr(owner, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be finite and non-negative, got {value}")


@dataclass(frozen=True)
class DroopGains:
    """Fast frequency response: ``v = -k_f dw`` (k_f: pu power per pu frequency, the machine's rating).

    The speed laws' defaults are the picks of the fair-tuning search (``nni-simulate --tune-laws``,
    :mod:`.law_tuning`, docs/laws.md) at b = 0.3 on the paper's case; config/controller.yaml ships the same.
    """

    k_f: float = 562.0

    def __post_init__(self) -> None:
        _positive(self, "k_f")

    def state_space(self):
        return np.zeros((0, 0)), np.zeros(0), np.zeros(0), -self.k_f


@dataclass(frozen=True)
class VsmGains:
    """Virtual inertia and damping: ``v = -(2 h_v s/(1 + s t_f_s) dw + d_v dw)``.

    h_v_s: virtual inertia constant (s, on the machine's rating); d_v: damping
    (pu power per pu frequency); t_f_s: the derivative's filter (s).
    """

    h_v_s: float = 1.25
    d_v: float = 316.0
    t_f_s: float = 0.05

    def __post_init__(self) -> None:
        _non_negative(self, "h_v_s", "d_v")
        _positive(self, "t_f_s")
        if self.h_v_s == 0 and self.d_v == 0:
            raise ValueError("h_v_s and d_v cannot both be 0 (the law would do nothing)")

    def state_space(self):
        # s/(1 + s T) = (1/T)(1 - 1/(1 + s T)): one state z' = (dw - z)/T, derivative (dw - z)/T.
        t = self.t_f_s
        m = 2.0 * self.h_v_s
        return np.array([[-1.0 / t]]), np.array([1.0 / t]), np.array([m / t]), -(m / t + self.d_v)


@dataclass(frozen=True)
class PssGains:
    """PSS1A on speed: gain k_s (pu power per pu frequency), washout t_w_s, lead-lags (t1/t2), (t3/t4), s."""

    k_s: float = 100.0
    t_w_s: float = 10.0
    t1_s: float = 0.05
    t2_s: float = 0.05
    t3_s: float = 0.05
    t4_s: float = 0.05

    def __post_init__(self) -> None:
        _positive(self, "k_s", "t_w_s", "t2_s", "t4_s")
        _non_negative(self, "t1_s", "t3_s")

    def state_space(self):
        # Three first-order sections in series, each x' = a x + b u, y = c x + d u:
        # washout s T/(1 + s T) = 1 - 1/(1 + s T); lead-lag (1 + s T1)/(1 + s T2) = T1/T2 + (1 - T1/T2)/(1 + s T2).
        sections = [(-1.0 / self.t_w_s, 1.0 / self.t_w_s, -1.0, 1.0)]
        for lead, lag in ((self.t1_s, self.t2_s), (self.t3_s, self.t4_s)):
            sections.append((-1.0 / lag, 1.0 / lag, 1.0 - lead / lag, lead / lag))
        a, b, c, d = series(sections)
        return a, b, -self.k_s * c, -self.k_s * d


GAINS = {"droop": DroopGains, "vsm": VsmGains, "pss": PssGains}


def series(sections):
    """The state space (A, B, C, D) of SISO first-order sections ``(a, b, c, d)`` in series, first to last."""
    n = len(sections)
    a_mat, b_vec, c_vec, d = np.zeros((n, n)), np.zeros(n), np.zeros(n), 1.0
    for i, (a, b, c, dd) in enumerate(sections):
        # Section i's input is the previous output y = c_prev x + d u; its x_i' = a x_i + b y.
        a_mat[i] = b * c_vec
        a_mat[i, i] = a
        b_vec[i] = b * d
        c_vec = dd * c_vec
        c_vec[i] = c
        d = dd * d
    return a_mat, b_vec, c_vec, d


def expm(matrix: np.ndarray) -> np.ndarray:
    """The matrix exponential by scaling and squaring of a Taylor series (small matrices; no scipy).

    The matrix is scaled by 2^-s to a norm below 1/2, where 20 terms of the
    series are exact to rounding (the remainder is below 2^-20 / 20!), then squared s times.
    """
    norm = float(np.abs(matrix).sum(axis=1).max()) if matrix.size else 0.0
    squarings = max(0, int(math.ceil(math.log2(norm / 0.5)))) if norm > 0.5 else 0
    scaled = matrix / 2.0 ** squarings
    result = term = np.eye(matrix.shape[0])
    for k in range(1, 21):
        term = term @ scaled / k
        result = result + term
    for _ in range(squarings):
        result = result @ result
    return result


def zero_order_hold(a: np.ndarray, b: np.ndarray, period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``(Ad, Bd)`` of ``z' = A z + B u`` with u held over ``period_s``: the exponential of [[A, B], [0, 0]] T."""
    n = a.shape[0]
    augmented = np.zeros((n + 1, n + 1))
    augmented[:n, :n], augmented[:n, n] = a, b
    exact = expm(augmented * period_s)
    return exact[:n, :n], exact[:n, n]


@dataclass(frozen=True)
class Law:
    """A law by name with its gains, and the battery limit b (in ``ctrl``).

    ``ctrl`` carries the NNI gains (tau, K, L, alpha) and, for every law, the
    battery limit b; ``gains`` the speed law's (:data:`GAINS`), its defaults when
    not given, and must be None for the NNI laws.
    """

    name: str = DEFAULT_LAW
    ctrl: ControllerParams = field(default_factory=ControllerParams)
    gains: object = None

    def __post_init__(self) -> None:
        if self.name not in LAW_NAMES:
            raise ValueError(f"unknown law {self.name!r} (laws: {', '.join(LAW_NAMES)})")
        if self.name in GAINS:
            if self.gains is None:
                object.__setattr__(self, "gains", GAINS[self.name]())
            elif not isinstance(self.gains, GAINS[self.name]):
                raise ValueError(f"law {self.name}: gains must be {GAINS[self.name].__name__}")
        elif self.gains is not None:
            raise ValueError(f"law {self.name} takes the NNI gains (tau, K, L, alpha), not {self.gains!r}")

    @property
    def uses_speed(self) -> bool:
        return self.name in SPEED_LAWS

    @property
    def limit_pu(self) -> float:
        return self.ctrl.battery_limit_pu

    def with_limit(self, limit_pu: float) -> "Law":
        return replace(self, ctrl=replace(self.ctrl, battery_limit_pu=limit_pu))

    def gain_values(self) -> dict:
        """The gains this law uses, by parameter name (what runs and recordings say ran)."""
        if self.gains is None:
            return {name: getattr(self.ctrl, name) for name in ("tau_s", "gain_k", "gain_l", "alpha")}
        return {f.name: getattr(self.gains, f.name) for f in fields(self.gains)}

    def describe(self) -> str:
        """``nni (tau_s 0.1, gain_k 1, ...)``: one line naming the law and its gains."""
        return f"{self.name} ({', '.join(f'{k} {v:g}' for k, v in self.gain_values().items())})"

    def filter_matrices(self, period_s: float):
        """``(Ad, Bd, C, D)`` of a speed law at this period (S states: Ad (S, S), Bd, C (S,), D float)."""
        a, b, c, d = self.gains.state_space()
        ad, bd = zero_order_hold(a, b, period_s) if a.size else (a, b)
        return ad, bd, c, float(d)

    def sampled(self, plant, period_s: float, omega0_rad_s: float | None = None, x3: float = 0.0):
        """This law for one generator, one call per measurement (:class:`SampledLaw`)."""
        return SampledLaw(self, plant, period_s, omega0_rad_s, x3)


class SampledLaw:
    """One generator's law, sampled: :meth:`step` answers a measurement, on Python floats.

    ``plant``: the SMIB model (g from it when not measured); ``omega0_rad_s``:
    the nominal frequency dw is measured against (the plant's when None).
    """

    def __init__(self, law: Law, plant, period_s: float, omega0_rad_s: float | None = None, x3: float = 0.0):
        self.spec = law
        self.limit_pu = law.limit_pu
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"sampling period must be finite and positive, got {period_s}")
        if law.uses_speed:
            omega0 = omega0_rad_s if omega0_rad_s is not None else plant.omega0_rad_s
            self._per_unit = 1.0 / omega0
            ad, bd, c, d = law.filter_matrices(period_s)
            self._ad = tuple(tuple(map(float, row)) for row in ad)
            self._bd, self._c, self._d = tuple(map(float, bd)), tuple(map(float, c)), d
            self.z = [0.0] * len(self._bd)
            self._nni = None
        else:
            ctrl = law.ctrl if law.name == "nni" else replace(law.ctrl, battery_limit_pu=math.inf)
            self._nni = SampledController(plant, ctrl, period_s, x3=x3)

    @property
    def x3(self) -> float:
        """The NNI law's state x3; for a speed law its filter's first state (0 for droop, which has none)."""
        if self._nni is not None:
            return self._nni.x3
        return self.z[0] if self.z else 0.0

    def reset(self) -> None:
        """Back to the pre-fault steady state (all states 0): data resumes after a gap."""
        if self._nni is not None:
            self._nni.reset()
        else:
            self.z = [0.0] * len(self.z)

    def step(self, angle_dev_rad: float, speed_rad_s: float, restoring_power_pu: float | None = None):
        """``(P_ST, demand v, saturated)`` for one measurement; advances the state.

        ``saturated``: the output is at the limit (|v| >= b). Non-finite input raises ValueError.
        """
        if self._nni is not None:
            power, w, saturated = self._nni.step(angle_dev_rad, restoring_power_pu)
            if self.spec.name == "nni":
                return power, w, saturated
            b = self.limit_pu
            return min(max(power, -b), b), w, abs(w) >= b
        if not math.isfinite(speed_rad_s):
            raise ValueError(f"speed must be finite, got {speed_rad_s}")
        u = speed_rad_s * self._per_unit
        z = self.z
        v = self._d * u
        for ci, zi in zip(self._c, z):
            v += ci * zi
        self.z = [bi * u + sum(a * zj for a, zj in zip(row, z)) for row, bi in zip(self._ad, self._bd)]
        b = self.limit_pu
        power = min(max(v, -b), b)
        if not (math.isfinite(power) and all(map(math.isfinite, self.z))):
            self.z = [0.0] * len(z)
            return 0.0, v, abs(v) >= b
        return power, v, abs(v) >= b


class ArrayLaw:
    """The laws on arrays: N generators (axis 0) times R runs (axis 1), one law per generator.

    ``laws``: one :class:`Law` per generator (gains on the machine's rating);
    ``scale``: per generator, system pu per machine pu (1 for the SMIB); the
    demand and the limits ``limits_pu`` (N, R) are on the system base. The NNI
    laws run :func:`.law.sampled_step` as the SMIB's SampledController does;
    the speed laws the same filters as :class:`SampledLaw`.
    """

    def __init__(self, laws, period_s: float, limits_pu: np.ndarray, omega0_rad_s: float, scale=None,
                 state=None):
        self.laws = tuple(laws)
        names = {law.name for law in self.laws}
        if len(names) != 1:
            raise ValueError(f"one law for every generator, got {sorted(names)}")
        self.name = names.pop()
        self.period_s, self.limits_pu = period_s, limits_pu
        n = len(self.laws)
        self.scale = np.ones(n) if scale is None else np.asarray(scale, dtype=float)
        if self.name in SPEED_LAWS:
            matrices = [law.filter_matrices(period_s) for law in self.laws]
            self._ad = np.array([m[0] for m in matrices])                    # (N, S, S)
            self._bd = np.array([m[1] for m in matrices])                    # (N, S)
            self._c = np.array([m[2] for m in matrices]) * self.scale[:, None]  # system base
            self._d = (np.array([m[3] for m in matrices]) * self.scale)[:, None]
            self._per_unit = 1.0 / omega0_rad_s
            states = self._bd.shape[1]
            self.state = np.zeros((states, n, limits_pu.shape[1])) if state is None else state
        else:
            ctrl = [law.ctrl for law in self.laws]
            self._k = (np.array([c.gain_k for c in ctrl]) * self.scale)[:, None]
            self._l = (np.array([c.gain_l for c in ctrl]) * self.scale)[:, None]
            self._decay_unsaturated = np.exp(-period_s / np.array([c.tau_s for c in ctrl]))[:, None]
            self._decay_saturated = np.exp(-np.array([c.alpha / c.gain_k for c in ctrl]) * period_s)[:, None]
            self.state = np.zeros(limits_pu.shape) if state is None else state

    @property
    def x3(self) -> np.ndarray:
        """(N, R): x3 of the NNI laws, a speed law's first filter state (0 for droop)."""
        if self.name in SPEED_LAWS:
            return self.state[0] if self.state.shape[0] else np.zeros(self.limits_pu.shape)
        return self.state

    def step(self, angle_dev_rad, speed_rad_s, restoring_power_pu):
        """``(P_ST, demand, saturated)`` (N, R), system base; advances the state."""
        b = self.limits_pu
        if self.name not in SPEED_LAWS:
            mode_limit = b if self.name == "nni" else np.inf
            power, w, saturated, self.state = sampled_step(
                self.state, angle_dev_rad, restoring_power_pu, self._k, self._l, mode_limit,
                self._decay_unsaturated, self._decay_saturated)
            if self.name == "nni":
                return power, w, saturated
            return np.nan_to_num(np.clip(w, -b, b), nan=0.0), w, np.abs(w) >= b
        u = speed_rad_s * self._per_unit
        z = self.state
        v = self._d * u + np.einsum("ns,snr->nr", self._c, z)
        self.state = np.einsum("nij,jnr->inr", self._ad, z) + self._bd.T[:, :, None] * u
        power = np.clip(v, -b, b)
        bad = ~(np.isfinite(power) & np.all(np.isfinite(self.state), axis=0))
        self.state = np.where(bad, 0.0, self.state)
        return np.where(bad, 0.0, power), v, np.abs(v) >= b


#: Node parameter (and --params-file key) of each speed law's gain: ``{law: {parameter: gain field}}``.
GAIN_PARAMETERS = {name: {f"{name}_{f.name}": f.name for f in fields(gains)} for name, gains in GAINS.items()}


def law_from_parameters(name: str, values: dict, ctrl: ControllerParams) -> Law:
    """The law ``name`` with its gains from node parameters ``values`` (GAIN_PARAMETERS' keys), b from ``ctrl``.

    ValueError naming the parameter when a gain is bad or the law unknown.
    """
    if name not in LAW_NAMES:
        raise ValueError(f"unknown law {name!r} (laws: {', '.join(LAW_NAMES)})")
    if name not in GAINS:
        return Law(name, ctrl)
    try:
        gains = GAINS[name](**{field_name: float(values[parameter])
                               for parameter, field_name in GAIN_PARAMETERS[name].items()})
    except ValueError as error:
        text = str(error)
        for parameter, field_name in GAIN_PARAMETERS[name].items():
            text = text.replace(f"{field_name} must", f"{parameter} must")
        raise ValueError(f"law {name}: {text}") from None
    return Law(name, ctrl, gains)
