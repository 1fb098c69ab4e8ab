"""One battery controller per generator of a network case: what each node of the deployment is given.

Used by ``nni-demo --case``, ``launch/network.launch.py`` and the bench, so
that all start the same nodes with the same parameters, read from the case (how many
generators, each one's pre-fault angle and power): generator i (1-based, case
order) is namespace ``gen<i>``, where the network plant node publishes its
PMU. Each controller runs the sampled H3-hat with g measured
(``restoring_power: measured``): g_i = P_m,i - P_e,i(measured), its angle
measured from its pre-fault angle, in pu of its machine's rating, as
:mod:`nni_battery_controller.network_sim` does offline. The controllers run in
one of two deployments (:func:`start_controllers`): a process each, or all
composed in one ``composed_controllers`` process on one executor. No ROS
import (the processes are started through the project's supervisor).
"""

from __future__ import annotations

import math

import numpy as np
import yaml

from nni_battery_controller.controller_config import generator_parameters
from nni_battery_controller.controller_config import parameters as controller_node_parameters
from nni_battery_controller.law import ControllerParams
from nni_battery_controller.laws import GAIN_PARAMETERS, law_from_parameters
from nni_battery_controller.network_sim import NetworkLaw
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_msgs_adapter.ros.readback import expected_parameters
from nni_plant_sim.cases import DEFAULT_FAULT_BUS
from nni_plant_sim.network_scenarios import AngleDisplacement, BusFault, LineTrip, MechanicalStep

#: How a case's controllers run: ``separate``, one controller_node process per generator; ``composed``, all of
#: them as nodes of one composed_controllers process on one executor (one substation computer).
DEPLOYMENTS = ("separate", "composed")
CONTROLLER_MODULE = "nni_battery_controller.controller_node"
COMPOSED_MODULE = "nni_battery_controller.composed_controllers"
#: composed_controllers' log and params file in the run's log folder.
COMPOSED_NAME = "composed_controllers"


def namespaces(net) -> tuple[str, ...]:
    """``("gen1", ..., "gen<N>")``: the network plant node's namespace of each generator, in case order."""
    return tuple(f"gen{i + 1}" for i in range(net.size))


def generator_limits(items, n: int, name: str = "--gen-b") -> dict[int, float]:
    """Per-generator battery limits from ``I=B`` words (I: generator number 1..n, B: pu or inf).

    ``name`` is the option or argument the words came from, for the messages.

    Returns ``{index (0-based): b}``; ValueError, naming the word, for a bad word,
    a generator outside 1..n, a negative or NaN b, or a generator given twice.
    """
    limits: dict[int, float] = {}
    for item in items:
        number, sep, value = item.partition("=")
        try:
            index, b = int(number) - 1, float(value)
        except ValueError:
            index, b = -1, math.nan
        if not sep or math.isnan(b):
            raise ValueError(f"{name} takes I=B (generator number, battery limit in pu or inf), got {item!r}")
        if not 0 <= index < n:
            raise ValueError(f"{name} {item}: no generator {number} (the case has gen1 .. gen{n})")
        if b < 0:
            raise ValueError(f"{name} {item}: a battery limit must be >= 0")
        if index in limits:
            raise ValueError(f"{name}: generator {index + 1} given twice")
        limits[index] = b
    return limits


def battery_limits(n: int, b: float, overrides: dict[int, float]) -> np.ndarray:
    """The limit of each generator in one run (pu of its rating): ``b``, except where ``overrides`` says."""
    limits = np.full(n, float(b))
    for index, value in overrides.items():
        limits[index] = value
    return limits


def default_law(net, name: str | None = None) -> NetworkLaw:
    """The controller node's default law (or ``name``) with its default gains (config/controller.yaml) at every generator."""
    values = controller_defaults()
    name = name or values["law"]
    gains = law_from_parameters(name, values, ControllerParams()).gains
    return NetworkLaw.uniform(net, values["tau_s"], values["gain_k"], values["gain_l"], values["alpha"], name=name,
                              gains=gains)


def law_parameters(law: NetworkLaw, index: int) -> dict:
    """Generator ``index``'s law as controller node parameters: the law, the NNI gains and the speed law's."""
    speed = {} if law.gains is None else {
        parameter: float(getattr(law.gains, field)) for parameter, field in GAIN_PARAMETERS[law.name].items()}
    return {"law": law.name, "tau_s": float(law.tau_s[index]), "gain_k": float(law.gain_k[index]),
            "gain_l": float(law.gain_l[index]), "alpha": float(law.alpha[index]), **speed}


def controller_parameters(net, index: int, limit_pu: float, rate_hz: float, law: NetworkLaw) -> dict:
    """Generator ``index``'s controller node parameters (pu of its machine's rating), its angle reference the law's.

    g measured (no SMIB model: IEEE 39's G10 at 1.0 pu of its rating runs as any other machine);
    :func:`controller_config.generator_parameters` gives the generator's own values.
    """
    return {**generator_parameters(net, index, law.reference), "battery_limit_pu": float(limit_pu),
            "sample_rate_hz": float(rate_hz), "f0_hz": float(net.f0_hz), **law_parameters(law, index)}


def default_fault_bus(case: str) -> int:
    """The bus a bus fault is at when none is given: the case's (``nni-simulate --case`` takes the same)."""
    return DEFAULT_FAULT_BUS[case]


def scenario_parameters(net, scenario, trip_line=()) -> dict:
    """The network plant node's scenario parameters for an offline scenario of ``net`` (``trip_line``: FROM TO [CIRCUIT])."""
    trip = {"trip_line": " ".join(map(str, trip_line))} if trip_line else {}
    if isinstance(scenario, LineTrip):
        return {"scenario": "line_trip", **trip}
    if isinstance(scenario, BusFault):
        return {"scenario": "bus_fault", "fault_bus": int(scenario.bus), "fault_r": float(scenario.impedance_pu.real),
                "fault_x": float(scenario.impedance_pu.imag), "clearing_time": float(scenario.clearing_time_s),
                **trip}
    if isinstance(scenario, MechanicalStep):  # the node takes P_m in pu of the machine's rating, as the CLI
        scale = float(net.mbase_mva[scenario.machine] / net.base_mva)
        return {"scenario": "mechanical_step", "step_p_mech": scenario.p_mech_pu / scale,
                "step_duration": float(scenario.duration_s), "machine": [int(net.gen_bus[scenario.machine])]}
    if isinstance(scenario, AngleDisplacement):
        moved = np.flatnonzero(scenario.displacement_rad)
        return {"scenario": "angle_displacement",
                "displace": float(scenario.displacement_rad[moved[0]]) if moved.size else 0.0,
                "machine": [int(net.gen_bus[i]) for i in moved]}
    raise ValueError(f"the network plant node does not run {type(scenario).__name__}")


def pmu_readers(net, reference: str) -> int:
    """Subscribers each generator's ``pmu`` has before the plant starts: the MCAP logger and its controller, or
    with the centre-of-inertia reference every controller (each reads every generator's PMU)."""
    return 1 + (net.size if reference == "coi" else 1)


def plant_parameters(case: str, scenario_values: dict, mode: str, rate_hz: float, duration_s: float,
                     limits, readers: int = 2) -> dict:
    """The network plant node's parameters for one run: each generator's battery rated its b (``limits``, case
    order), its run held until the read-back, waiting for ``readers`` on each generator's pmu."""
    return {"case": case, **scenario_values, "mode": mode, "pmu_rate_hz": float(rate_hz),
            "duration_s": float(duration_s), "wait_for_subscribers": int(readers),
            "battery_ratings_pu": [float(b) for b in limits], "hold_until_released": True}


def participants(net, deployment: str, others: int) -> int:
    """The DDS participants (processes) of a run: its controllers (one per generator, or one composed process)
    and ``others`` (the plant, the logger, a Rerun bridge); the deployment's ``NNI_DDS_PARTICIPANTS``."""
    return (net.size if deployment == "separate" else 1) + others


def composed_parameters(controllers: dict) -> dict:
    """The params file of ``composed_controllers`` for ``{namespace: parameters}``: one section per node."""
    return {f"{ns}/controller": {"ros__parameters": values} for ns, values in controllers.items()}


def start_controllers(procs, controllers: dict, deployment: str, env: dict | None = None) -> list:
    """Start the controllers ``{absolute namespace: node parameters}`` under supervisor ``procs`` (``env`` added to
    their environment: the run's key); the children.

    ``separate``: one ``controller_node`` process per namespace (log ``controller_gen<i>``); ``composed``: one
    ``composed_controllers`` process with a params file of a section per node, written to the log folder.
    """
    if deployment not in DEPLOYMENTS:
        raise ValueError(f"deployment must be one of {', '.join(DEPLOYMENTS)}, got {deployment!r}")
    if deployment == "separate":
        return [procs.start_node(f"controller_{ns.strip('/')}", CONTROLLER_MODULE, values, ("-r", f"__ns:={ns}"),
                                 env) for ns, values in controllers.items()]
    procs.log_dir.mkdir(parents=True, exist_ok=True)
    path = procs.log_dir / f"{COMPOSED_NAME}.yaml"
    path.write_text(yaml.safe_dump(composed_parameters(controllers), default_flow_style=False))
    return [procs.start_node(COMPOSED_NAME, COMPOSED_MODULE, {"namespaces": list(controllers)},
                             ("--params-file", str(path)), env)]


def controller_readbacks(children: list, controllers: dict, deployment: str) -> list:
    """``(child, {node: the parameters it must state})`` of the controllers :func:`start_controllers` started:
    each controller node its table's defaults and its own values, the composed host its namespaces."""
    stated = {f"{ns}/controller": expected_parameters(controller_node_parameters(), values)
              for ns, values in controllers.items()}
    if deployment == "separate":
        return [(child, {node: values}) for child, (node, values) in zip(children, stated.items())]
    tuning = next(spec.default for spec in controller_node_parameters() if spec.name == "allow_tuning")
    return [(children[0], {f"/{COMPOSED_NAME}": {"namespaces": list(controllers), "allow_tuning": tuning}, **stated})]
