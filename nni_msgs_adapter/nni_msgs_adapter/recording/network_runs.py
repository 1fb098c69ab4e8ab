"""A recorded network run: every generator of one case on the samples they share (pure: numpy, no rclpy).

The network plant (``nni_plant_sim.network_plant_node``) reports generator i of a case
(1-based, case order) under ``/gen<i>``, each with a SMIB's topics; a recording reads
into one :class:`recording.runs.GeneratorRun` per namespace. Here they become one
system again: the instants every generator reported (the plant reports all of them at
each instant, lockstep and realtime), angles relative to the centre of inertia (weights
the machines' M from the case), and the offline network analysis
(:func:`nni_battery_controller.network_sim.assess_network`) on the recorded samples.

Which case a recording is of is the run's business: its ``nni_run`` metadata names it
under :data:`CASE_KEY` (``nni-demo --case`` writes it; a logger started by hand is given
it in ``run_metadata``). A recording that does not name one is shown generator by
generator, each as its controller measured it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import reduce

import numpy as np

#: Key of the ``nni_run`` metadata that names the run's network case (a name ``load_network`` knows).
CASE_KEY = "case"


def generator_namespaces(size: int) -> tuple[str, ...]:
    """The namespaces the network plant gives the generators of a case of ``size`` machines."""
    return tuple(f"/gen{i + 1}" for i in range(size))


def recorded_case(parameters: dict | None) -> str | None:
    """The network case the run's parameters name, or None (no parameters, or a SMIB run).

    Raises
    ------
    ValueError
        If the key is there but not a non-empty string.
    """
    if parameters is None or CASE_KEY not in parameters:
        return None
    case = parameters[CASE_KEY]
    if not isinstance(case, str) or not case:
        raise ValueError(f"run parameter {CASE_KEY!r} must name a case, got {case!r}")
    return case


@dataclass(frozen=True)
class NetworkRun:
    """N generators of ``net`` at the n instants all of them reported. Arrays ``(n, N)`` unless said.

    Attributes
    ----------
    net : nni_plant_sim.network.Network
        The case (M, ratings, names).
    namespaces : tuple of str
        ``/gen1`` .. ``/genN``, case order.
    stamp_ns : numpy.ndarray of int64, shape (n,)
        Common ``plant/state`` stamps, ns.
    delta_rad, speed_rad_s : numpy.ndarray
        Rotor angle (rad, the case's reference) and speed deviation (rad/s).
    battery_power_pu : numpy.ndarray
        Battery power in force from each instant on, pu of the machine's rating (as on the wire).
    commanded_power_pu : numpy.ndarray
        The power the controller answered the instant with (its ``controller/state``), pu of the
        machine's rating; NaN where it did not answer (the run's last instant).
    saturated : numpy.ndarray of bool
        The controller's saturation flag (False where it did not answer).
    limits_pu : numpy.ndarray, shape (N,)
        Each controller's battery limit b, pu of its machine's rating (inf: unsaturated; NaN: never reported).
    """

    net: object
    namespaces: tuple
    stamp_ns: np.ndarray
    delta_rad: np.ndarray
    speed_rad_s: np.ndarray
    battery_power_pu: np.ndarray
    commanded_power_pu: np.ndarray
    saturated: np.ndarray
    limits_pu: np.ndarray

    @property
    def answered(self) -> np.ndarray:
        """``(n, N)``: the instants each controller answered."""
        return ~np.isnan(self.commanded_power_pu)

    @property
    def t_s(self) -> np.ndarray:
        """Time since the first common instant, s."""
        return (self.stamp_ns - self.stamp_ns[0]) * 1e-9

    def coi_angle_rad(self) -> np.ndarray:
        """``delta_i - delta_COI`` (rad), ``delta_COI = sum M_i delta_i / sum M_i``."""
        return self.delta_rad - self.net.coi(self.delta_rad.T)[:, None]


def network_run(net, runs: dict) -> NetworkRun:
    """Put a recording's generator runs (namespace -> ``GeneratorRun``) together as the network ``net``.

    Raises
    ------
    ValueError
        If the namespaces are not ``/gen1`` .. ``/genN`` of the case, or the generators share no instant.
    """
    expected = generator_namespaces(net.size)
    if tuple(sorted(runs, key=namespace_order)) != expected:
        raise ValueError(f"the case has {net.size} machines, reported under {', '.join(expected)}; "
                         f"the recording holds {', '.join(runs) or 'none'}")
    ordered = [runs[namespace] for namespace in expected]
    stamps = reduce(np.intersect1d, [run.stamp_ns for run in ordered])
    if stamps.size == 0:
        raise ValueError("the generators' plant states share no instant")
    rows = [np.searchsorted(run.stamp_ns, stamps) for run in ordered]

    def column(values) -> np.ndarray:
        return np.column_stack([value[row] for value, row in zip(values, rows)])

    return NetworkRun(net, expected, stamps, column(run.delta_rad for run in ordered),
                      column(run.speed_rad_s for run in ordered), column(run.battery_power_pu for run in ordered),
                      column(run.signals["battery_power"] for run in ordered), column(run.saturated for run in ordered),
                      np.array([run.battery_limit_pu for run in ordered], dtype=np.float64))


def namespace_order(namespace: str) -> tuple:
    """``/gen2`` before ``/gen10``; anything else after, by name."""
    tail = namespace[len("/gen"):]
    return (0, int(tail), "") if namespace.startswith("/gen") and tail.isdigit() else (1, math.inf, namespace)
