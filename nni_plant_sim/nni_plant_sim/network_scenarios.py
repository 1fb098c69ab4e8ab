"""Disturbances of a network of generators: what the reduced network and the mechanical powers do over time.

The network counterparts of :mod:`nni_plant_sim.scenarios`, with the same
protocol for :func:`nni_plant_sim.integrators.advance`: ``initial_state(net)``
(shape (2, N): angles and speed deviations), ``network(t_s, net)`` giving
``(P_m vector pu, Coupling in force)`` and ``breakpoints()`` (the times it
jumps), and ``narrowed(keep)`` for the runs ``keep`` of a batch. Times are
seconds since the disturbance. Pure numpy: no ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from nni_plant_sim.network import Coupling, Network, Switched


class _FromEquilibrium:
    """A disturbance that starts from the pre-fault equilibrium."""

    def initial_state(self, net: Network) -> np.ndarray:
        """Pre-fault equilibrium."""
        return np.stack((net.delta_bar_rad, np.zeros(net.size)))


class _SameInEveryRun:
    """A disturbance that does not differ between the runs of a batch."""

    def narrowed(self, keep):
        """The scenario for a subset of a batch's runs: itself."""
        return self


@dataclass(frozen=True)
class BusFault(_FromEquilibrium):
    """Three-phase fault at ``bus`` through ``impedance_pu`` (system base), cleared at ``clearing_time_s``.

    Clearing removes the fault and trips the branches ``trip`` (indices; none:
    the pre-fault network returns). ``clearing_time_s`` may be an array of R
    clearing times (one per run of a batch): the runs then share one
    integration, each switching at its own instant. Starts from the pre-fault
    equilibrium.
    """

    net: Network
    bus: int
    clearing_time_s: object = 0.1
    impedance_pu: complex = 0.0
    trip: tuple = ()
    _during: Coupling = field(init=False, repr=False)
    _after: Coupling = field(init=False, repr=False)
    #: The first and the last clearing instant, s: read at every integrated period and every measurement.
    _clearing_span: tuple = field(init=False, repr=False)

    def __post_init__(self) -> None:
        clearing = np.asarray(self.clearing_time_s, dtype=float)
        if not (np.all(np.isfinite(clearing)) and np.all(clearing > 0)):
            raise ValueError(f"clearing time must be finite and positive, got {self.clearing_time_s}")
        if not math.isfinite(abs(self.impedance_pu)) or self.impedance_pu.real < 0:
            raise ValueError(f"fault impedance must be finite with R >= 0, got {self.impedance_pu}")
        object.__setattr__(self, "_during", self.net.faulted(self.bus, self.impedance_pu))
        object.__setattr__(self, "_after", self.net.without(self.trip) if self.trip else self.net.coupling)
        object.__setattr__(self, "_clearing_span", (float(clearing.min()), float(clearing.max())))

    def network(self, t_s: float, net: Network):
        """Faulted network until clearing (per run for an array of clearing times), then the post-fault one.

        Between the first and the last clearing time of a batch each run gets its own (:class:`Switched`).
        """
        first, last = self._clearing_span
        if t_s < first:
            return net.p_mech_pu, self._during
        if t_s >= last:
            return net.p_mech_pu, self._after
        return net.p_mech_pu, Switched(self._during, self._after, t_s < np.asarray(self.clearing_time_s))

    def narrowed(self, keep) -> "BusFault":
        """The same fault for the runs ``keep`` (boolean, shape (R,)) of a batch of clearing times."""
        if np.ndim(self.clearing_time_s) == 0:
            return self
        return replace(self, clearing_time_s=np.asarray(self.clearing_time_s)[keep])

    def breakpoints(self) -> tuple[float, ...]:
        """The clearing instant(s)."""
        return tuple(float(t) for t in np.unique(np.asarray(self.clearing_time_s, dtype=float)))


@dataclass(frozen=True)
class LineTrip(_FromEquilibrium, _SameInEveryRun):
    """The branches ``trip`` (indices) open at t = 0 without a fault; starts from the pre-fault equilibrium."""

    net: Network
    trip: tuple
    _after: Coupling = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.trip:
            raise ValueError("a line trip needs at least one branch to trip")
        object.__setattr__(self, "_after", self.net.without(self.trip))

    def network(self, t_s: float, net: Network):
        """The network without the tripped branches."""
        return net.p_mech_pu, self._after

    def breakpoints(self) -> tuple[float, ...]:
        """None: the trip is at t = 0."""
        return ()


@dataclass(frozen=True)
class MechanicalStep(_FromEquilibrium, _SameInEveryRun):
    """Generator ``machine`` (index) runs at ``p_mech_pu`` (system base) for ``duration_s`` (inf: for good)."""

    machine: int
    p_mech_pu: float
    duration_s: float = math.inf

    def __post_init__(self) -> None:
        if not (math.isfinite(self.p_mech_pu) and self.p_mech_pu >= 0):
            raise ValueError(f"mechanical power during the step must be finite and >= 0, got {self.p_mech_pu}")
        if not self.duration_s > 0:
            raise ValueError(f"duration of the power step must be positive, got {self.duration_s}")

    def network(self, t_s: float, net: Network):
        """Pre-fault network; the stepped machine's P_m until ``duration_s``."""
        p_mech = net.p_mech_pu.copy()
        if t_s < self.duration_s:
            p_mech[self.machine] = self.p_mech_pu
        return p_mech, net.coupling

    def breakpoints(self) -> tuple[float, ...]:
        """The end of the step, if it ends."""
        return (self.duration_s,) if math.isfinite(self.duration_s) else ()


@dataclass(frozen=True)
class AngleDisplacement(_SameInEveryRun):
    """Rotor angles start displaced by ``displacement_rad`` (shape (N,)) from equilibrium, network intact."""

    displacement_rad: np.ndarray

    def __post_init__(self) -> None:
        if not np.all(np.isfinite(self.displacement_rad)):
            raise ValueError("angle displacements must be finite")

    def initial_state(self, net: Network) -> np.ndarray:
        """Equilibrium plus the displacement, at rest."""
        return np.stack((net.delta_bar_rad + self.displacement_rad, np.zeros(net.size)))

    def network(self, t_s: float, net: Network):
        """The pre-fault network and powers."""
        return net.p_mech_pu, net.coupling

    def breakpoints(self) -> tuple[float, ...]:
        """None."""
        return ()


@dataclass(frozen=True)
class InitialStates(_SameInEveryRun):
    """Run r starts from its own state, network intact: angles ``angle_dev_rad[:, r]`` from equilibrium and speed
    deviations ``speed_rad_s[:, r]`` (each (N, R)); the post-fault system of a region-of-attraction sweep."""

    angle_dev_rad: np.ndarray
    speed_rad_s: np.ndarray

    def __post_init__(self) -> None:
        if np.shape(self.angle_dev_rad) != np.shape(self.speed_rad_s) or np.ndim(self.angle_dev_rad) != 2:
            raise ValueError("initial angles and speeds must both be (N, R)")
        if not (np.all(np.isfinite(self.angle_dev_rad)) and np.all(np.isfinite(self.speed_rad_s))):
            raise ValueError("initial angles and speeds must be finite")

    def initial_state(self, net: Network) -> np.ndarray:
        """(2, N, R): equilibrium plus each run's displacement, at each run's speed."""
        return np.stack((net.delta_bar_rad[:, None] + self.angle_dev_rad, np.asarray(self.speed_rad_s, dtype=float)))

    def network(self, t_s: float, net: Network):
        """The pre-fault network and powers."""
        return net.p_mech_pu, net.coupling

    def breakpoints(self) -> tuple[float, ...]:
        """None."""
        return ()


#: The scenarios of a network (what :func:`from_values` builds) and, per scenario-specific value (the
#: network plant node's parameter names), the scenarios it belongs to.
NETWORK_SCENARIOS = ("bus_fault", "line_trip", "mechanical_step", "angle_displacement")
SCENARIO_PARAMETERS = {
    "fault_bus": ("bus_fault",), "fault_r": ("bus_fault",), "fault_x": ("bus_fault",),
    "clearing_time": ("bus_fault",), "trip_line": ("bus_fault", "line_trip"),
    "step_p_mech": ("mechanical_step",), "step_duration": ("mechanical_step",),
    "displace": ("angle_displacement",), "machine": ("mechanical_step", "angle_displacement"),
}


def machine_index(net: Network, bus: int) -> int:
    """Index of the generator at external bus ``bus``; ValueError naming the generators' buses when none is there."""
    where = np.flatnonzero(net.gen_bus == bus)
    if where.size != 1:
        raise ValueError(f"machine {bus}: no generator at that bus (generators at {', '.join(map(str, net.gen_bus))})")
    return int(where[0])


def from_values(net: Network, values: dict):
    """The disturbance ``values["scenario"]`` names, from the values of :data:`SCENARIO_PARAMETERS`.

    ``trip_line``: ``"FROM TO [CIRCUIT]"`` or empty; ``machine``: generator
    bus numbers (one for mechanical_step); ``step_p_mech``: pu of the machine's
    rating; ``fault_r``, ``fault_x``: pu on the system base. The values of
    other scenarios are not read. ValueError names what is wrong or missing.
    """
    scenario = values["scenario"]
    if scenario not in NETWORK_SCENARIOS:
        raise ValueError(f"scenario must be one of {', '.join(NETWORK_SCENARIOS)}, got {scenario!r}")
    if scenario in ("bus_fault", "line_trip"):
        words = values["trip_line"].split()
        if len(words) not in (0, 2, 3) or not all(w.isdigit() for w in words):
            raise ValueError(f"trip_line takes 'FROM TO [CIRCUIT]', got {values['trip_line']!r}")
        trip = (net.bus_model.branch_index(*map(int, words)),) if words else ()
        if scenario == "line_trip":
            if not trip:
                raise ValueError("scenario line_trip needs trip_line")
            return LineTrip(net, trip)
        net.bus_model.bus_index(values["fault_bus"])
        return BusFault(net, values["fault_bus"], values["clearing_time"],
                        complex(values["fault_r"], values["fault_x"]), trip)
    if not len(values["machine"]):
        raise ValueError(f"scenario {scenario} needs machine (generator bus numbers)")
    machines = [machine_index(net, bus) for bus in values["machine"]]
    if scenario == "mechanical_step":
        if len(machines) != 1:
            raise ValueError(f"scenario mechanical_step needs one machine, got {list(values['machine'])}")
        p_mech = float(net.pu_of_machine(np.full(net.size, values["step_p_mech"]))[machines[0]])
        return MechanicalStep(machines[0], p_mech, values["step_duration"])
    displacement = np.zeros(net.size)
    displacement[machines] = values["displace"]
    return AngleDisplacement(displacement)
