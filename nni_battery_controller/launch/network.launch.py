"""Launch a network case: the network plant, one battery controller per generator of the case, the MCAP logger.

    ros2 launch nni_battery_controller network.launch.py case:=ieee39 mode:=lockstep duration_s:=10.0 \
        battery_limit_pu:=0.1 gen_b:='3=0.2 10=inf' fault_bus:=16 clearing_time:=0.1 output_path:=ieee39.mcap
    ros2 launch nni_battery_controller network.launch.py scenario:=mechanical_step machine:=2 step_p_mech:=0.95 \
        step_duration:=0.2

The controllers are not listed here: the case is read when the launch runs
(an OpaqueFunction), and it starts one controller node per generator, in
namespace ``/gen<i>`` (generator i in case order, where the network plant
publishes its PMU), each with g measured from its PMU and its angle from its
pre-fault value (:mod:`nni_battery_controller.network_deployment`, the same
parameters ``nni-demo --case`` gives). ``battery_limit_pu`` is every
generator's b, ``gen_b`` ('I=B ...') overrides it per generator; the gains are
the same at every generator. The disturbance arguments (every scenario of the
network plant: ``bus_fault``, ``line_trip``, ``mechanical_step``,
``angle_displacement``) are generated from the network plant node's parameter
table, with its names, defaults and descriptions, and checked as the node
checks them (``network_plant_config.scenario_from``: an argument of another
scenario is refused, not ignored; ``fault_bus`` empty: the case's default bus,
7 Kundur and the ring, 16 IEEE 39). Each node reads its defaults from its
package's config YAML; the launch passes only what it sets. Every process is
told how many the launch starts (``NNI_DDS_PARTICIPANTS``), so that the 54 of
``kundur_ring_52`` discover each other. The launch shuts down when the plant exits: the controllers and the
logger get SIGINT, and the logger finishes the recording. ``pmu_port`` (-1:
none) serves every generator's PMU as an IEEE C37.118.2 stream, a station
each, on that TCP port of ``pmu_host`` (loopback by default), IDCODE
``pmu_idcode``. With ``measurements:=c37118`` the controllers read
``c37118/pmu``, fed from that stream (on port 4712 when ``pmu_port`` gives
none) by a ``c37118_client`` node (as ``nni-demo --measurements c37118``).

Each launch makes a fresh command key (the plant's and the controllers' ``NNI_COMMAND_KEY_FILE``, removed at
shutdown), gives each generator's battery its b as its rating (``battery_ratings_pu``), and starts the plant's
run only once every node has stated at start the parameters the launch gave it (:func:`readbacks`,
:mod:`nni_msgs_adapter.ros.launch_trust`); on a difference it logs one line and shuts down.

``launch`` is imported inside :func:`generate_launch_description` only, so
that :func:`network_nodes` (the nodes a launch would create, as plain dicts)
can be imported and checked where ``launch`` is not installed.
"""

import math

import yaml

from nni_battery_controller.demo_c37118 import client_host, client_parameters, launch_stream, plant_readers
from nni_battery_controller.demo_c37118 import controller_parameters as measurement_topic
from nni_battery_controller.demo_foxglove import launch_bridge
from nni_battery_controller.controller_config import parameters as controller_node_parameters
from nni_battery_controller.network_deployment import (
    battery_limits,
    controller_parameters,
    default_fault_bus,
    generator_limits,
    namespaces,
    participants,
    plant_parameters,
)
from nni_battery_controller.law import ControllerParams
from nni_battery_controller.laws import law_from_parameters
from nni_battery_controller.network_sim import NetworkLaw
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_msgs_adapter.ros.processes import PARTICIPANTS_ENV
from nni_msgs_adapter.ros.readback import expected_parameters
from nni_plant_sim.cases import CASES, load_network
from nni_plant_sim.network_plant_config import parameters as plant_node_parameters, scenario_from
from nni_plant_sim.network_scenarios import SCENARIO_PARAMETERS

#: Launch arguments other than the disturbance's: name -> (default, description). Numbers are read as ROS reads
#: parameter text (YAML). The disturbance's come from the network plant node's table (:func:`arguments`).
RUN_ARGUMENTS = {
    "case": ("kundur_two_area", f"shipped test system ({', '.join(CASES)})"),
    "mode": ("lockstep", "lockstep (simulated /clock) or realtime"),
    "duration_s": ("10.0", "simulated seconds to run, then shut down"),
    "pmu_rate_hz": ("50.0", "PMU reporting rate, frames/s (and the controllers' sampling rate)"),
    "battery_limit_pu": ("0.1", "every generator's battery limit b, pu of its rating (.inf: unlimited)"),
    "gen_b": ("", "per-generator limits instead, 'I=B ...' (I: 1.. as in /gen<I>)"),
    "battery_energy_pu_s": (".inf", "every generator's battery energy, pu s of its rating, from half charge (as much "
                                    "room to absorb; .inf: unlimited)"),
    "law": (None, "the battery law at every generator: nni, nni-unsaturated, droop, vsm or pss (a speed law with its "
                  "gains from config/controller.yaml)"),
    "tau_s": (None, "tau, s, at every generator"),
    "gain_k": (None, "K, pu/rad, at every generator"),
    "gain_l": (None, "L, pu/rad, at every generator (K < L)"),
    "alpha": (None, "alpha at every generator"),
    "output_path": ("network.mcap", "the MCAP recording of every namespace"),
    "measurements": ("ros", "how the controllers get the measurements: ros (the plant's pmu topics) or c37118 (the "
                     "plant's IEEE C37.118.2 stream on pmu_port, 4712 if none, read by the c37118_client node)"),
    "foxglove": ("false", "true: a foxglove_bridge node streams every loop topic live over the Foxglove WebSocket "
                          "protocol at foxglove_address"),
    "foxglove_address": ("127.0.0.1:8765", "[HOST:]PORT of the Foxglove server (loopback unless a host is named)"),
}
#: The network plant node's disturbance parameters, the launch arguments of the same names.
SCENARIO_ARGUMENTS = ("scenario", *SCENARIO_PARAMETERS)
#: The network plant node's C37.118 stream parameters, the launch arguments of the same names.
STREAM_ARGUMENTS = ("pmu_port", "pmu_host", "pmu_idcode")
#: (package, executable) of each node.
PLANT = ("nni_plant_sim", "network_plant_node")
CONTROLLER = ("nni_battery_controller", "controller_node")
LOGGER = ("nni_msgs_adapter", "mcap_logger")
CLIENT = ("nni_msgs_adapter", "c37118_client")
FOXGLOVE = ("nni_msgs_adapter", "foxglove_bridge")


def _text(value) -> str:
    """A parameter default as launch text: ``.inf``, words for an array, YAML for the rest."""
    if isinstance(value, float) and math.isinf(value):
        return ".inf" if value > 0 else "-.inf"
    if isinstance(value, (list, tuple)):
        return " ".join(map(str, value))
    return str(value)


def arguments() -> dict:
    """Every launch argument: name -> (default as launch text, description).

    The disturbance's are the network plant node's parameter table (name, default, description; which
    scenario each belongs to from ``SCENARIO_PARAMETERS``); ``fault_bus`` empty is the case's default bus.
    The gains' defaults are the controller's config YAML.
    """
    gains = controller_defaults()
    table = {name: (str(gains[name]) if default is None else default, text)
             for name, (default, text) in RUN_ARGUMENTS.items()}
    specs = {spec.name: spec for spec in plant_node_parameters()}
    for name in SCENARIO_ARGUMENTS:
        spec = specs[name]
        text = spec.description.rstrip(".")
        if spec.choices:
            text += f" ({' | '.join(spec.choices)})"
        if spec.array_of is not None:
            text += "; space-separated"
        table[name] = (_text(spec.default), text)
    for name in STREAM_ARGUMENTS:
        table[name] = (_text(specs[name].default), specs[name].description.rstrip("."))
    bus = table["fault_bus"][1]
    table["fault_bus"] = ("", f"{bus} (empty: 7 Kundur and the ring, 16 IEEE 39)")
    return table


def argument_defaults() -> dict:
    """Every argument's default as launch text."""
    return {name: default for name, (default, _) in arguments().items()}


def _value(text: str):
    return yaml.safe_load(text)


def _scenario_value(spec, text: str):
    """A disturbance argument's text as its plant parameter's type; ValueError naming the argument."""
    try:
        if spec.array_of is not None:
            return [spec.array_of(word) for word in text.split()]
        if isinstance(spec.default, str):
            return text
        value = _value(text)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError
        return type(spec.default)(value)
    except (ValueError, TypeError, yaml.YAMLError):
        kind = "bus numbers 'BUS ...'" if spec.array_of is not None else "a number"
        raise ValueError(f"{spec.name} takes {kind}, got {text!r}") from None


def scenario_values(net, case: str, values: dict) -> dict:
    """The network plant node's disturbance parameters for these launch argument texts, checked by the plant's own
    check (``network_plant_config.scenario_from``): an argument of another scenario given (not at its default)
    is refused, and so is a bus, branch or machine not in the case. Returns the scenario and its own values."""
    specs = {spec.name: spec for spec in plant_node_parameters()}
    given = {name: _scenario_value(specs[name], values[name]) for name in SCENARIO_ARGUMENTS
             if name != "fault_bus" or values[name]}
    if given["scenario"] == "bus_fault":
        given.setdefault("fault_bus", default_fault_bus(case))
    merged = {**{name: specs[name].default for name in SCENARIO_ARGUMENTS}, **given}
    scenario_from(net, merged)
    return {"scenario": merged["scenario"], **{name: merged[name] for name, scenarios in SCENARIO_PARAMETERS.items()
                                                if merged["scenario"] in scenarios}}


def stream_values(values: dict) -> dict:
    """The network plant node's C37.118 stream parameters for these launch argument texts (port -1: none)."""
    specs = {spec.name: spec for spec in plant_node_parameters()}
    try:
        return {name: type(specs[name].default)(values[name]) for name in STREAM_ARGUMENTS}
    except ValueError:
        raise ValueError(f"pmu_port and pmu_idcode take integers, got {values['pmu_port']!r} and "
                         f"{values['pmu_idcode']!r}") from None


def network_nodes(given: dict) -> list[dict]:
    """The nodes a launch with these argument texts creates: ``package``, ``executable``, ``name``,
    ``namespace``, ``parameters`` (one dict), ``env`` (what the process gets beside the launch's environment);
    the logger first, then the controllers, the Foxglove bridge and the C37.118 client if asked for, the plant last.

    ValueError (or CliError) naming a bad argument: an unknown case, a bus, branch or machine not in it, an
    argument of another scenario, K >= L, a bad ``gen_b`` word.
    """
    values = {**argument_defaults(), **given}
    case = values["case"]
    net = load_network(case)
    scenario = scenario_values(net, case, values)
    rate = float(_value(values["pmu_rate_hz"]))
    law_name = values["law"]
    gains = law_from_parameters(law_name, controller_defaults(), ControllerParams()).gains
    law = NetworkLaw.uniform(net, *(float(_value(values[name])) for name in ("tau_s", "gain_k", "gain_l", "alpha")),
                             name=law_name, gains=gains)
    limits = battery_limits(net.size, float(_value(values["battery_limit_pu"])),
                            generator_limits(values["gen_b"].split(), net.size, "gen_b"))
    measurements, stream = values["measurements"], stream_values(values)
    port, client_stream = launch_stream(measurements, stream["pmu_port"], stream["pmu_host"])
    stream.update(client_stream)
    bridge = launch_bridge(values["foxglove"], values["foxglove_address"], {
        "case": case, "b": limits.tolist(), "law": law_name, "scenario": scenario["scenario"], "mode": values["mode"]})
    plant = {**plant_parameters(case, scenario, values["mode"], rate, float(_value(values["duration_s"])), limits,
                                plant_readers(measurements, 2, bridge is not None)),
             "wait_for_recorders": 1 + (bridge is not None), **stream,  # on plant/state: the logger and the bridge
             "battery_energy_pu_s": float(_value(values["battery_energy_pu_s"]))}
    nodes = [{"package": LOGGER[0], "executable": LOGGER[1], "name": "mcap_logger", "namespace": "",
              "parameters": {"output_path": values["output_path"]}}]
    nodes += [{"package": CONTROLLER[0], "executable": CONTROLLER[1], "name": "controller", "namespace": ns,
               "parameters": {**controller_parameters(net, i, limits[i], rate, law), **measurement_topic(measurements)}}
              for i, ns in enumerate(namespaces(net))]
    if bridge is not None:
        nodes.append({"package": FOXGLOVE[0], "executable": FOXGLOVE[1], "name": "foxglove_bridge", "namespace": "",
                      "parameters": bridge})
    if measurements == "c37118":  # it connects once the controllers and the logger read each c37118/pmu
        nodes.append({"package": CLIENT[0], "executable": CLIENT[1], "name": "c37118_client", "namespace": "",
                      "parameters": client_parameters(port, values["mode"], 2, [f"/{ns}" for ns in namespaces(net)],
                                                      client_host(stream["pmu_host"]), stream["pmu_idcode"])})
    nodes.append({"package": PLANT[0], "executable": PLANT[1], "name": "network_plant", "namespace": "",
                  "parameters": plant})
    # Every process learns how many there are: beyond 32 (the ring's 54) their discovery is widened to cover them.
    env = {PARTICIPANTS_ENV: str(participants(net, "separate", 2 + (measurements == "c37118") + (bridge is not None)))}
    return [{**node, "env": env} for node in nodes]


def readbacks(nodes: list[dict]) -> list[dict]:
    """Per node of :func:`network_nodes`: ``{its fully qualified name: the parameters it must state at start}``
    (the plant and the controllers; nothing for the logger, the C37.118 client and the Foxglove bridge, which only have to have stated
    theirs: read the run's key, removed once every node has)."""
    tables = {CONTROLLER[1]: controller_node_parameters(), PLANT[1]: plant_node_parameters()}
    return [{"/".join(("", *filter(None, (node["namespace"].strip("/"), node["name"])))):
             expected_parameters(tables[node["executable"]], node["parameters"]) if node["executable"] in tables
             else {}} for node in nodes]


def generate_launch_description():
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
    from launch.event_handlers import OnProcessExit
    from launch.events import Shutdown
    from launch_ros.actions import Node

    from nni_msgs_adapter.ros.launch_trust import readback_release, run_key_environment

    def setup(context):
        specs = network_nodes({name: context.launch_configurations[name] for name in table})
        key_env, remove_key = run_key_environment()  # every node's: each seals what it sends, checks what it reads
        nodes = [Node(package=spec["package"], executable=spec["executable"], name=spec["name"],
                      namespace=spec["namespace"], parameters=[spec["parameters"]],
                      additional_env={**spec["env"], **key_env})
                 for spec in specs]
        started = [(node, passed) for node, passed in zip(nodes, readbacks(specs)) if passed]
        # The plant (the last node) runs once every node stated what it was given; the run is over when it
        # exits: stop the others, finish the recording.
        return [*remove_key, *readback_release(started, nodes[-1], key_env), *nodes,
                RegisterEventHandler(OnProcessExit(target_action=nodes[-1], on_exit=[
                    EmitEvent(event=Shutdown(reason="the network plant finished its run"))]))]

    table = arguments()
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, text) in table.items()),
        OpaqueFunction(function=setup),
    ])
