"""Fault scenarios: how the network seen by the generator changes after a fault.

A scenario gives the initial rotor state when the fault starts and the mechanical
power and maximum transfer in force at each time since the fault started. Times
are seconds since the fault started (the plant node starts the clock on its
``start_fault`` service or at start-up; the offline simulation at t = 0).
Pure python: no ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from nni_plant_sim.model import SmibParams, require_finite


@dataclass(frozen=True)
class InitialAngle:
    """The paper's case: the fault has already moved the rotor to ``delta0`` and cleared.

    Parameters
    ----------
    delta0_rad : float
        Rotor angle delta(0) in rad right after the fault (paper: 0.2).
    speed0_rad_s : float
        Speed deviation delta'(0) in rad/s (paper: 0).
    """

    delta0_rad: float = 0.2
    speed0_rad_s: float = 0.0

    def __post_init__(self) -> None:
        require_finite(self)
        if not (math.isfinite(self.delta0_rad) and math.isfinite(self.speed0_rad_s)):
            raise ValueError("delta0_rad and speed0_rad_s must be finite")

    def initial_state(self, plant: SmibParams) -> np.ndarray:
        """``[delta (rad), speed deviation (rad/s)]`` when the fault starts."""
        return np.array([self.delta0_rad, self.speed0_rad_s])

    def network(self, t_s: float, plant: SmibParams) -> tuple[float, float]:
        """``(P_M, P_max)`` in pu at ``t_s`` seconds after the fault: pre-fault values."""
        return plant.p_mech_pu, plant.p_max_pu

    def breakpoints(self) -> tuple[float, ...]:
        """Times (s after the fault) where ``network`` jumps: none."""
        return ()


@dataclass(frozen=True)
class MechanicalPowerStep:
    """Mechanical power steps to ``p_mech_pu`` for ``duration_s``; ``inf`` (the one way
    to write "for good") is a permanent step, which moves the equilibrium.

    Starts from the pre-fault equilibrium.
    """

    p_mech_pu: float = 0.95
    duration_s: float = math.inf

    def __post_init__(self) -> None:
        require_finite(self)
        if not math.isfinite(self.p_mech_pu) or self.p_mech_pu < 0:
            raise ValueError(f"p_mech_pu during the step must be finite and >= 0, got {self.p_mech_pu}")
        if not self.duration_s > 0:
            raise ValueError(f"duration_s of the power step must be positive, got {self.duration_s}")

    def initial_state(self, plant: SmibParams) -> np.ndarray:
        """Pre-fault equilibrium ``[delta_bar, 0]``."""
        return np.array([plant.delta_bar_rad, 0.0])

    def network(self, t_s: float, plant: SmibParams) -> tuple[float, float]:
        """Stepped mechanical power until ``duration_s``, then the pre-fault value."""
        return (self.p_mech_pu if t_s < self.duration_s else plant.p_mech_pu), plant.p_max_pu

    def breakpoints(self) -> tuple[float, ...]:
        """The end of the step, if it ends."""
        return (self.duration_s,) if math.isfinite(self.duration_s) else ()


@dataclass(frozen=True)
class TransferLimitFault:
    """A network fault lowers P_max to ``p_max_fault_pu`` until it clears at ``clearing_time_s``.

    The classic three-phase fault: ``p_max_fault_pu = 0`` for a bolted fault at
    the generator terminals. Starts from the pre-fault equilibrium.
    """

    p_max_fault_pu: float = 0.0
    clearing_time_s: float = 0.1

    def __post_init__(self) -> None:
        require_finite(self)
        if not math.isfinite(self.p_max_fault_pu) or self.p_max_fault_pu < 0:
            raise ValueError(f"p_max_fault_pu must be finite and >= 0, got {self.p_max_fault_pu}")
        if not (math.isfinite(self.clearing_time_s) and self.clearing_time_s > 0):
            raise ValueError(f"clearing_time_s must be finite and positive, got {self.clearing_time_s}")

    def initial_state(self, plant: SmibParams) -> np.ndarray:
        """Pre-fault equilibrium ``[delta_bar, 0]``."""
        return np.array([plant.delta_bar_rad, 0.0])

    def network(self, t_s: float, plant: SmibParams) -> tuple[float, float]:
        """Faulted transfer limit until clearing, then the pre-fault value."""
        return plant.p_mech_pu, (self.p_max_fault_pu if t_s < self.clearing_time_s else plant.p_max_pu)

    def breakpoints(self) -> tuple[float, ...]:
        """The clearing instant."""
        return (self.clearing_time_s,)


Scenario = InitialAngle | MechanicalPowerStep | TransferLimitFault

SCENARIOS = {
    "initial_angle": InitialAngle,
    "mechanical_step": MechanicalPowerStep,
    "transfer_limit_fault": TransferLimitFault,
}

#: The values each scenario is built from, by parameter name (the plant node's
#: parameter names, which the command-line options mirror).
SCENARIO_FIELDS = {
    "initial_angle": ("delta0_rad", "speed0_rad_s"),
    "mechanical_step": ("step_p_mech_pu", "step_duration_s"),
    "transfer_limit_fault": ("fault_p_max_pu", "clearing_time_s"),
}


def from_values(values) -> Scenario:
    """The scenario ``values["scenario"]`` names, built from its fields in ``values``.

    ``values`` maps the plant node's parameter names (``scenario`` and the
    names in :data:`SCENARIO_FIELDS`) to values, e.g. a node's parameters or
    ``plant.yaml``; the other scenarios' fields may be present and are not read.
    ValueError for an unknown scenario name.
    """
    name = values["scenario"]
    if name not in SCENARIOS:
        raise ValueError(f"scenario must be one of {', '.join(SCENARIOS)}, got {name!r}")
    return SCENARIOS[name](*(float(values[field]) for field in SCENARIO_FIELDS[name]))


@dataclass(frozen=True)
class StartingAt:
    """A scenario whose fault starts at ``start_s`` on a longer time axis.

    Before ``start_s`` the network is that of ``before`` (the pre-fault one: for
    the SMIB, any :class:`InitialAngle`; for a network of generators, a scenario
    of :mod:`nni_plant_sim.network_scenarios` with the intact network); from then
    on it is ``scenario`` shifted in time. The plant nodes use it when the fault
    is triggered by a service call at an arbitrary instant.
    """

    scenario: Scenario
    start_s: float
    before: object = InitialAngle()

    def initial_state(self, plant: SmibParams) -> np.ndarray:
        """The scenario's state at its start."""
        return self.scenario.initial_state(plant)

    def network(self, t_s: float, plant: SmibParams) -> tuple[float, float]:
        """``before``'s values before ``start_s``, then the shifted scenario."""
        if t_s < self.start_s:
            return self.before.network(t_s, plant)
        return self.scenario.network(t_s - self.start_s, plant)

    def breakpoints(self) -> tuple[float, ...]:
        """The start and the scenario's own breakpoints, shifted."""
        return self._breakpoints

    @cached_property
    def _breakpoints(self) -> tuple[float, ...]:
        # Asked for once per integrated period, on the plant's critical path: built once.
        return (self.start_s, *(self.start_s + tb for tb in self.scenario.breakpoints()))

