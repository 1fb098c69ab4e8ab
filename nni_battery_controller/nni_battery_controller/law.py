"""Angle-feedback battery controllers H3 (unsaturated) and H3-hat (saturated NNI).

Paper section VI, with input u3 = angle deviation d (rad) and scalar state x3:

    w      = x3 - L d - g(d)                 battery power the law asks for (pu)
    P_ST   = sat_b(w)                        battery power it gets (pu)
    x3'    = -x3/tau + (K/tau) d   if |w| <  b
    x3'    = -(alpha/K) x3         if |w| >= b

``b = inf`` is the unsaturated H3 (P_ST = w, closed loop linear); ``b = 0`` is
no battery. The sampled-data law holds its mode and output for one period T and
advances x3 with the exact solution of the active mode's linear ODE for d held
at its sample (zero-order hold). Pure numpy: no ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nni_plant_sim.model import SmibParams, require_finite, restoring_energy, restoring_power


@dataclass(frozen=True)
class ControllerParams:
    """Design parameters of the (saturated) phase-lead NNI controller.

    Parameters
    ----------
    tau_s : float
        Time constant tau of the phase-lead state, s. Must be > 0.
    gain_k : float
        Gain K of x3 toward the angle deviation, pu power/rad. Must be > 0 and < L.
    gain_l : float
        Direct angle feedback L, pu power/rad. Must be > K (stability condition K - L < 0).
    alpha : float
        Decay rate factor of x3 in saturation (x3' = -(alpha/K) x3), pu. Must be > 0.
    battery_limit_pu : float
        Battery power limit b, pu; ``inf`` for an unlimited battery, 0 for none. Must be >= 0.
    """

    tau_s: float = 0.1
    gain_k: float = 1.0
    gain_l: float = 1.1
    alpha: float = 1.0
    battery_limit_pu: float = math.inf

    def __post_init__(self) -> None:
        require_finite(self)
        for name in ("tau_s", "gain_k", "gain_l", "alpha"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)}")
        if self.tau_s <= 0:
            raise ValueError(f"tau must be positive (tau_s > 0), got {self.tau_s}")
        if self.gain_k <= 0:
            raise ValueError(f"K must be positive (gain_k > 0), got {self.gain_k}")
        if self.gain_l <= 0:
            raise ValueError(f"L must be positive (gain_l > 0), got {self.gain_l}")
        if self.gain_k >= self.gain_l:
            raise ValueError(
                f"K must be less than L: the stability condition K - L < 0 "
                f"(gain_k={self.gain_k}, gain_l={self.gain_l})"
            )
        if self.alpha <= 0:
            raise ValueError(f"alpha must be positive (alpha > 0), got {self.alpha}")
        if self.battery_limit_pu < 0:
            raise ValueError(f"battery limit b must be non-negative (b >= 0), got {self.battery_limit_pu}")


def saturation_input(x3, angle_dev_rad, ctrl: ControllerParams, plant: SmibParams):
    """Saturation variable ``w = x3 - L d - g(d)`` in pu; vectorised."""
    return x3 - ctrl.gain_l * angle_dev_rad - restoring_power(angle_dev_rad, plant)


def saturate(w, limit_pu: float):
    """``sat_b(w)``: ``w`` clipped to ``[-b, b]``; vectorised. NaN maps to 0 (no power)."""
    return np.nan_to_num(np.clip(w, -limit_pu, limit_pu), nan=0.0)


def is_saturated(w, limit_pu: float):
    """The saturated mode ``|w| >= b``; vectorised."""
    return np.abs(w) >= limit_pu


def last_saturated(instants, limit_pu: float) -> float | None:
    """The last of the saturated ``instants`` (s), None if there are none or there is no battery.

    With b = 0 the mode ``|w| >= b`` holds at every instant, but there is no
    battery to saturate and so no saturation to leave: tables print "-".
    """
    return float(np.max(instants)) if limit_pu > 0 and np.size(instants) else None


def x3_rate(x3, angle_dev_rad, saturated, ctrl: ControllerParams):
    """Controller state derivative x3' in pu/s for the given mode; vectorised."""
    return np.where(
        saturated,
        -(ctrl.alpha / ctrl.gain_k) * x3,
        (ctrl.gain_k * angle_dev_rad - x3) / ctrl.tau_s,
    )


def q1_matrix(inertia_m: float, gain_k: float, gain_l: float) -> np.ndarray:
    """Q1 of Theorem 2: W = 1/2 [d', d, x3] Q1 [d', d, x3]^T for the unsaturated loop.

    ``Q1 = [[M, 0, 0], [0, L, -1], [0, -1, 1/K]]``, positive definite exactly when
    K < L (given M, K > 0). Takes raw gains so that it can be evaluated for gains
    that ControllerParams rejects.
    """
    return np.array([[inertia_m, 0.0, 0.0], [0.0, gain_l, -1.0], [0.0, -1.0, 1.0 / gain_k]])


def closed_loop_lyapunov(angle_dev_rad, speed_rad_s, x3, plant: SmibParams, ctrl: ControllerParams, saturated=None):
    """Candidate W_hat = V1 + V3 - F of the loop (H1, H3-hat) (paper section IV); vectorised.

    ``V1 = (M/2) d'^2``, ``V3 = x3^2 / (2K)`` and F as the paper defines it, by
    the mode at the current w:

        w <= -b:   F = G(d) - b d
        |w| < b:   F = x3 d - L d^2 / 2
        w >= b:    F = G(d) + b d

    with ``G(d) = int_0^d g``. Within a mode W_hat does not increase along
    trajectories; at a mode switch it jumps (see README, "What the theory
    promises and what we check"). ``saturated`` (bool, broadcastable), when
    given, is the mode in force instead of the one read from w: a run sliding
    on |w| = b has |w| within rounding of b on either side, and the mode must
    not flicker with it.
    """
    b = ctrl.battery_limit_pu
    w = saturation_input(x3, angle_dev_rad, ctrl, plant)
    unsaturated = x3 * angle_dev_rad - 0.5 * ctrl.gain_l * np.square(angle_dev_rad)
    with np.errstate(invalid="ignore"):
        saturated_f = restoring_energy(angle_dev_rad, plant) + np.sign(w) * b * angle_dev_rad
    f = np.where(is_saturated(w, b) if saturated is None else saturated, saturated_f, unsaturated)
    return 0.5 * plant.inertia_m * np.square(speed_rad_s) + np.square(x3) / (2.0 * ctrl.gain_k) - f


@dataclass
class SampledController:
    """Sampled-data H3-hat for one generator: one call per measurement.

    Parameters
    ----------
    plant : SmibParams or None
        Supplies delta_bar and P_max for g(d); None where g is always given (measured).
    ctrl : ControllerParams
        Gains and the battery limit b.
    period_s : float
        Sampling period T = 1/fs in s. Must be > 0.
    x3 : float
        Controller state, pu; starts at 0 (the pre-fault steady state).
    """

    plant: SmibParams | None
    ctrl: ControllerParams
    period_s: float
    x3: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.period_s) and self.period_s > 0):
            raise ValueError(f"sampling period must be finite and positive, got {self.period_s}")
        # One period of each mode's exact solution: x3 decays by these factors.
        self._decay_unsaturated = math.exp(-self.period_s / self.ctrl.tau_s)
        self._decay_saturated = math.exp(-self.ctrl.alpha * self.period_s / self.ctrl.gain_k)
        # g(d) = P_max (sin(delta_bar) - sin(d + delta_bar)): the constants, computed once (asin included).
        if self.plant is not None:
            self._delta_bar = self.plant.delta_bar_rad
            self._p_max = self.plant.p_max_pu
            self._sin_delta_bar = math.sin(self._delta_bar)

    def reset(self) -> None:
        """Back to the pre-fault steady state x3 = 0 (used when data resumes after a gap)."""
        self.x3 = 0.0

    def step(self, angle_dev_rad: float, restoring_power_pu: float | None = None) -> tuple[float, float, bool]:
        """Answer one measurement: returns ``(P_ST pu, w pu, saturated)`` and advances x3.

        ``restoring_power_pu`` is g, where it is measured: for a generator in a
        network g_i = P_e,i(pre-fault) - P_e,i(measured). Without it, g is the
        SMIB's g(d) = P_max (sin(delta_bar) - sin(d + delta_bar)) from the model
        (a controller without a model, ``plant`` None, must be given g). The update itself is :func:`sampled_step` (the network simulation runs
        the same function on arrays).

        Scalar Python arithmetic on purpose: this runs once per measurement on
        the controller's critical path, where numpy's per-call overhead on
        scalars cost ~150 us of the loop's latency (measured, cold caches at
        100 frames/s) against ~25 us for this. The offline sampled simulation
        calls this same method.

        A non-finite input must be dropped by the caller; here it raises
        ValueError rather than poison x3.
        """
        if not math.isfinite(angle_dev_rad):
            raise ValueError(f"angle deviation must be finite, got {angle_dev_rad}")
        if restoring_power_pu is None:
            if self.plant is None:
                raise ValueError("this controller has no plant model: g must be given")
            # g(d) on Python floats (math.sin, constants from __post_init__).
            restoring_power_pu = self._p_max * (self._sin_delta_bar - math.sin(angle_dev_rad + self._delta_bar))
        elif not math.isfinite(restoring_power_pu):
            raise ValueError(f"restoring power g must be finite, got {restoring_power_pu}")
        power, w, saturated, self.x3 = sampled_step(
            self.x3, angle_dev_rad, restoring_power_pu, self.ctrl.gain_k, self.ctrl.gain_l,
            self.ctrl.battery_limit_pu, self._decay_unsaturated, self._decay_saturated)
        return power, w, saturated


def sampled_step(x3, angle_dev_rad, restoring_power_pu, gain_k, gain_l, limit_pu, decay_unsaturated,
                 decay_saturated):
    """One period of the sampled-data H3-hat: ``(P_ST, w, saturated, next x3)``, floats or arrays alike.

    The mode (|w| >= b) and the output sat_b(w) are decided from the sample
    and held for one period T; x3 then advances by the exact solution of that
    mode's linear ODE with d held (zero-order hold):

        w             = x3 - L d - g
        unsaturated:  x3+ = e^(-T/tau) x3 + (1 - e^(-T/tau)) K d
        saturated:    x3+ = e^(-alpha T/K) x3

    ``decay_*`` are those factors. Python floats (one generator, the
    controller's critical path) stay floats; arrays (every generator of a
    network, many runs: all arguments broadcast) are computed elementwise by
    the same formulas. Where w or x3+ is not finite (finite but absurd inputs,
    |d| near 1e308, can overflow) the output is zero power and x3 restarts at
    0, so the command is always finite and within +-b.
    """
    w = x3 - gain_l * angle_dev_rad - restoring_power_pu
    held = decay_saturated * x3
    tracking = decay_unsaturated * x3 + (1.0 - decay_unsaturated) * gain_k * angle_dev_rad
    if isinstance(w, float):
        saturated = abs(w) >= limit_pu
        next_x3 = held if saturated else tracking
        power = min(max(w, -limit_pu), limit_pu)
        if not (math.isfinite(power) and math.isfinite(next_x3)):
            return 0.0, w, saturated, 0.0
        return power, w, saturated, next_x3
    saturated = np.abs(w) >= limit_pu
    next_x3 = np.where(saturated, held, tracking)
    power = np.clip(w, -limit_pu, limit_pu)
    bad = ~(np.isfinite(power) & np.isfinite(next_x3))
    return np.where(bad, 0.0, power), w, saturated, np.where(bad, 0.0, next_x3)
