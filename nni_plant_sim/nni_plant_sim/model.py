"""Single-machine-infinite-bus (SMIB) generator: parameters, swing equation, analysis.

Pure numpy: no ROS import. The one copy of the physics, used by the offline
simulation, the region-of-attraction sweep and the plant node alike.

Symbols follow the paper (section V): per unit powers, angles in rad, time in s.

    M * delta'' = P_M + P_ST - P_max * sin(delta) - D * delta'
    M = 2 H / omega0,  omega0 = 2 pi f0
    sin(delta_bar) = P_M / P_max          (pre-fault equilibrium, battery idle)

Deviation coordinates: ``angle_dev = delta - delta_bar`` with
``g(angle_dev) = P_max sin(delta_bar) - P_max sin(angle_dev + delta_bar)``, so that
``M angle_dev'' + D angle_dev' = g(angle_dev) + P_ST``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields

import numpy as np

from nni_plant_sim import network


def require_finite(owner: object) -> None:
    """Raise ValueError naming every float field of a dataclass that is NaN.

    Infinity is left to the per-field checks (the battery limit may be inf).
    """
    for field in fields(owner):
        value = getattr(owner, field.name)
        if isinstance(value, float) and math.isnan(value):
            raise ValueError(f"{field.name} must be a finite number, got NaN")


@dataclass(frozen=True)
class SmibParams:
    """Generator and network data of the SMIB system, per unit on the machine base.

    Parameters
    ----------
    inertia_h_s : float
        Inertia constant H in seconds (MJ/MVA). Must be > 0.
    damping_pu : float
        Damping coefficient D in pu power per rad/s. Must be >= 0.
    p_mech_pu : float
        Pre-fault mechanical power P_M in pu. Must satisfy 0 <= P_M < P_max.
    p_max_pu : float
        Maximum electrical power transfer P_max = |Vg||Vs|/X in pu. Must be > 0.
    f0_hz : float
        Nominal frequency f0 in Hz. Must be > 0.
    """

    inertia_h_s: float = 4.0
    damping_pu: float = 0.0
    p_mech_pu: float = 0.8
    p_max_pu: float = 1.0
    f0_hz: float = 50.0

    def __post_init__(self) -> None:
        require_finite(self)
        for name in ("inertia_h_s", "damping_pu", "p_mech_pu", "p_max_pu", "f0_hz"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)}")
        if self.inertia_h_s <= 0:
            raise ValueError(f"H must be positive (inertia_h_s > 0), got {self.inertia_h_s}")
        if self.damping_pu < 0:
            raise ValueError(f"D must be non-negative (damping_pu >= 0), got {self.damping_pu}")
        if self.f0_hz <= 0:
            raise ValueError(f"f0 must be positive (f0_hz > 0), got {self.f0_hz}")
        if self.p_max_pu <= 0:
            raise ValueError(f"P_max must be positive (p_max_pu > 0), got {self.p_max_pu}")
        if self.p_mech_pu < 0:
            raise ValueError(f"P_M must be non-negative (p_mech_pu >= 0), got {self.p_mech_pu}")
        if self.p_mech_pu >= self.p_max_pu:
            raise ValueError(
                f"P_M must be less than P_max: P_M >= P_max has no stable equilibrium "
                f"(p_mech_pu={self.p_mech_pu}, p_max_pu={self.p_max_pu})"
            )

    # Cached (the parameters are frozen): the swing equation reads M at every RK4 stage, 40 times a
    # sample on the plant node's path, where recomputing it was a sixth of a period's integration.
    @functools.cached_property
    def omega0_rad_s(self) -> float:
        """Nominal angular frequency omega0 = 2 pi f0 in rad/s."""
        return 2.0 * math.pi * self.f0_hz

    @functools.cached_property
    def inertia_m(self) -> float:
        """Inertia M = 2H/omega0 in pu power s^2/rad."""
        return 2.0 * self.inertia_h_s / self.omega0_rad_s

    @property
    def delta_bar_rad(self) -> float:
        """Pre-fault stable equilibrium angle delta_bar = asin(P_M/P_max) in rad."""
        return math.asin(self.p_mech_pu / self.p_max_pu)


def restoring_power(angle_dev_rad, plant: SmibParams):
    """Nominal nonlinear feedback g(angle_dev) in pu (paper's g).

    ``g(d) = P_max sin(delta_bar) - P_max sin(d + delta_bar)``; vectorised.
    """
    delta_bar = plant.delta_bar_rad
    return plant.p_max_pu * (math.sin(delta_bar) - np.sin(angle_dev_rad + delta_bar))


def restoring_energy(angle_dev_rad, plant: SmibParams):
    """Integral of g from 0 to angle_dev, in pu power * rad; vectorised.

    ``G(d) = P_max (d sin(delta_bar) + cos(d + delta_bar) - cos(delta_bar))``.
    """
    delta_bar = plant.delta_bar_rad
    return plant.p_max_pu * (
        angle_dev_rad * math.sin(delta_bar) + np.cos(angle_dev_rad + delta_bar) - math.cos(delta_bar)
    )


def swing_acceleration(delta_rad, speed_rad_s, battery_power_pu, plant: SmibParams, p_mech_pu: float,
                       p_max_pu: float):
    """Rotor acceleration delta'' in rad/s^2: the swing equation with a battery at the generator bus.

    ``M delta'' = P_M + P_ST - P_max sin(delta) - D delta'``: the network's swing
    equation (:func:`nni_plant_sim.network.swing_acceleration`) with the one
    machine's electrical power against the infinite bus, ``P_e = P_max sin(delta)``
    (what :func:`nni_plant_sim.network.electrical_power` gives for
    :meth:`nni_plant_sim.network.Network.from_smib`, bit for bit). Python floats in,
    float out (``math.sin``: the plant node's path, 40 calls a sample, where
    numpy's per-call overhead on scalars would dominate); numpy arrays in,
    array out (vectorised over trajectories). A diverged state (inf) gives NaN
    in both, as numpy does, rather than math's domain error.

    Parameters
    ----------
    delta_rad, speed_rad_s : float or numpy.ndarray
        Rotor angle delta (rad) and speed deviation delta' = omega - omega0 (rad/s).
    battery_power_pu : float or numpy.ndarray
        Battery power change P_ST injected at the generator bus, pu.
    plant : SmibParams
        Inertia and damping.
    p_mech_pu, p_max_pu : float
        Mechanical power and maximum transfer in force now (a fault scenario
        changes them over time; see :mod:`nni_plant_sim.scenarios`).
    """
    if isinstance(delta_rad, float):
        try:
            sine = math.sin(delta_rad)
        except ValueError:  # +-inf (NaN goes through as NaN); cheaper than testing every call
            sine = math.nan
    else:
        sine = np.sin(delta_rad)
    return network.swing_acceleration(p_mech_pu, battery_power_pu, p_max_pu * sine, speed_rad_s, plant.damping_pu,
                                      plant.inertia_m)


def plant_rate(t: float, x: tuple, u, params) -> tuple:
    """The swing equation as a system: ``(delta, speed)' = (speed, delta'')``.

    Parameters
    ----------
    t : float
        Time, s (unused: the network in force is in ``params``, constant over a step).
    x : tuple
        ``(delta rad, speed deviation rad/s)``: floats; arrays (N,) for N SMIB
        runs; arrays (N,) or (N, R) for a network of N generators (R runs).
    u : float or numpy.ndarray
        Battery power P_ST, pu, broadcasting against the state's components.
    params : tuple
        ``(plant, network_in_force)``: a :class:`SmibParams` or a
        :class:`~nni_plant_sim.network.Network`, and what its scenario's
        ``network(t, plant)`` gives.

    Returns
    -------
    tuple
        ``(delta' rad/s, delta'' rad/s^2)``, shaped as ``x``.
    """
    delta, speed = x
    plant, (p_mech, coupling) = params
    return speed, acceleration_of(plant)(delta, speed, u, plant, p_mech, coupling)


def acceleration_of(plant):
    """The swing equation of a SMIB (:class:`SmibParams`) or of a network of generators."""
    return swing_acceleration if isinstance(plant, SmibParams) else network.network_acceleration


def held_acceleration(plant, p_mech_pu, network_in_force, battery_power_pu, delta_rad):
    """The swing equation over a stretch with its powers held: a function ``(delta, speed) -> delta''``.

    :func:`acceleration_of` the plant with ``battery_power_pu`` and what the
    scenario's ``network(t, plant)`` gives bound. For a SMIB on floats (``delta_rad``
    a float: the plant node's path, 40 stages a sample) it is
    :func:`swing_acceleration` written out with the sum ``P_M + P_ST`` and the
    parameters bound once: the same operations in the same order, so bit for bit
    the same result (tests/test_plant_model.py), in one call a stage instead of two
    (measured: a period's RK4 24 -> 10 us). That float form raises ValueError
    where ``math.sin`` does (delta infinite); :func:`acceleration_of`'s form gives NaN.
    """
    if isinstance(plant, SmibParams) and isinstance(delta_rad, float) and isinstance(battery_power_pu, float):
        drive, p_max, damping, inertia, sin = (p_mech_pu + battery_power_pu, network_in_force, plant.damping_pu,
                                               plant.inertia_m, math.sin)
        return lambda delta, speed: (drive - p_max * sin(delta) - damping * speed) / inertia
    acceleration = acceleration_of(plant)
    return lambda delta, speed: acceleration(delta, speed, battery_power_pu, plant, p_mech_pu, network_in_force)


def swing_rhs(x, battery_power_pu, plant: SmibParams, p_mech_pu: float, p_max_pu: float):
    """:func:`plant_rate` of the SMIB on a state array, ``x' = f(x)``, for ODE solvers.

    Parameters
    ----------
    x : array_like, shape (2,) or (2, N)
        ``[delta (rad), speed deviation delta' = omega - omega0 (rad/s)]``.
    battery_power_pu, plant, p_mech_pu, p_max_pu
        As :func:`swing_acceleration`.

    Returns
    -------
    numpy.ndarray, same shape as ``x``
        ``[delta' (rad/s), delta'' (rad/s^2)]``.
    """
    state = (np.asarray(x[0], dtype=float), np.asarray(x[1], dtype=float))
    rate = plant_rate(0.0, state, battery_power_pu, (plant, (p_mech_pu, p_max_pu)))
    return np.stack(np.broadcast_arrays(*rate)).astype(float, copy=False)


def electrical_power(delta_rad, p_max_pu: float):
    """Electrical power output P_E = P_max sin(delta) in pu; vectorised."""
    return p_max_pu * np.sin(delta_rad)


# --- analysis of the uncontrolled plant (paper section V) -------------------------------


def equal_area_margin(delta0_rad: float, plant: SmibParams) -> float:
    """Left side of the equal area criterion (paper eq. eac), normalised by P_max.

    ``(pi - delta_bar - delta0) sin(delta_bar) - cos(delta_bar) - cos(delta0)``.
    Negative means the undamped, uncontrolled machine released at rest from
    ``delta0`` stays in synchronism.
    """
    delta_bar = plant.delta_bar_rad
    return (math.pi - delta_bar - delta0_rad) * math.sin(delta_bar) - math.cos(delta_bar) - math.cos(delta0_rad)


def eac_stable(delta0_rad: float, plant: SmibParams) -> bool:
    """True when the undamped machine released at rest from ``delta0`` stays in synchronism.

    The equal area criterion (a negative margin) decides it below the unstable
    equilibrium ``pi - delta_bar``. From there on P_E <= P_M and the rotor
    accelerates away (the margin, which has a local maximum 0 at that point, is
    negative again beyond it and must not be read there). ``delta0`` in
    (-pi, pi) rad.
    """
    return delta0_rad < math.pi - plant.delta_bar_rad and equal_area_margin(delta0_rad, plant) < 0.0


def _bisect(fun, lo: float, hi: float, tol: float = 1e-13) -> float:
    """Root of ``fun`` on [lo, hi] where ``fun(lo)`` and ``fun(hi)`` differ in sign."""
    f_lo = fun(lo)
    if f_lo * fun(hi) > 0:
        raise ValueError("bisection interval does not bracket a sign change")
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if (fun(mid) > 0) == (f_lo > 0):
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def critical_angles_rad(plant: SmibParams) -> tuple[float, float]:
    """Initial angles delta0 (released at rest) at the edge of the equal area criterion.

    Returns ``(low, high)``: the machine stays in synchronism for
    ``low < delta0 < high``. ``high`` is the unstable equilibrium
    ``pi - delta_bar``; ``low`` solves the EAC with equality below delta_bar.
    """
    delta_bar = plant.delta_bar_rad
    high = math.pi - delta_bar
    return _bisect(lambda d0: equal_area_margin(d0, plant), -math.pi + 1e-9, delta_bar), high


def lyapunov_w(angle_dev_rad, speed_rad_s, plant: SmibParams):
    """Lyapunov function W of the uncontrolled plant in pu power * rad; vectorised.

    ``W = (M/2) d'^2 + P_max (cos(delta_bar) - d sin(delta_bar) - cos(d + delta_bar))``.
    """
    return 0.5 * plant.inertia_m * np.square(speed_rad_s) - restoring_energy(angle_dev_rad, plant)


def invariant_set_level(plant: SmibParams) -> float:
    """Supremum of admissible levels c for Omega (paper eq. c), in pu power * rad.

    ``Gamma(pi - 2 delta_bar) = P_max (2 cos(delta_bar) - (pi - 2 delta_bar) sin(delta_bar))``.
    Any ``0 < c`` below this value gives an invariant set.
    """
    delta_bar = plant.delta_bar_rad
    return plant.p_max_pu * (2.0 * math.cos(delta_bar) - (math.pi - 2.0 * delta_bar) * math.sin(delta_bar))


def in_invariant_set(angle_dev_rad, speed_rad_s, plant: SmibParams, level: float | None = None):
    """Membership of Omega = {W <= c, |d| <= pi - 2 delta_bar}; vectorised.

    ``level`` defaults to the supremum from :func:`invariant_set_level` (the
    closure of the largest such set).
    """
    c = invariant_set_level(plant) if level is None else level
    if not 0.0 < c <= invariant_set_level(plant):
        raise ValueError(f"invariant set level c must satisfy 0 < c <= {invariant_set_level(plant)}, got {c}")
    bound = math.pi - 2.0 * plant.delta_bar_rad
    return (lyapunov_w(angle_dev_rad, speed_rad_s, plant) <= c) & (np.abs(angle_dev_rad) <= bound)


def invariant_set_boundary(plant: SmibParams, level: float | None = None, points: int = 400) -> np.ndarray:
    """Closed boundary curve of Omega in the (angle_dev rad, speed rad/s) plane.

    Returns an array of shape (2*points + 1, 2), first point repeated last. On the
    boundary ``(M/2) d'^2 = c + G(d)`` where ``c + G(d) >= 0``.
    """
    c = invariant_set_level(plant) if level is None else level
    bound = math.pi - 2.0 * plant.delta_bar_rad
    # Left edge: where c + G(d) = 0 below zero (G(d) < 0 for d != 0 near the origin).
    left = _bisect(lambda d: c + restoring_energy(d, plant), -math.pi - 2.0 * plant.delta_bar_rad + 1e-9, 0.0)
    right = bound if c + restoring_energy(bound, plant) >= 0 else _bisect(
        lambda d: c + restoring_energy(d, plant), 0.0, bound
    )
    d = np.linspace(left, right, points)
    speed = np.sqrt(np.maximum(2.0 * (c + restoring_energy(d, plant)) / plant.inertia_m, 0.0))
    upper = np.column_stack((d, speed))
    lower = np.column_stack((d[::-1], -speed[::-1]))
    curve = np.vstack((upper, lower))
    return np.vstack((curve, curve[:1]))
