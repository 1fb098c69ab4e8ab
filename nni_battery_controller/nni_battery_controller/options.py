"""Scenario, plant model and gain options shared by ``nni-simulate`` and ``nni-demo`` (and their default battery limits, the paper's); the link options of ``nni-simulate``.

One helper adds the same options, with the same names and defaults, to both
command lines; the defaults are the nodes' own (the package YAML files, read
through :mod:`nni_msgs_adapter.ros.defaults` when the parser is built, not at
import). Values are resolved in this order, later wins: the package YAML,
``--params-file`` (a ROS params file in the nodes' format), the command line.
Each value is kept under the node parameter name it sets, so that what a demo
passes to its nodes and what the assessment models are the same numbers.

An option that does not apply to the chosen scenario is refused, naming it.
Pure python: no ROS import.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import yaml

from nni_battery_controller.law import ControllerParams
from nni_msgs_adapter.ros.cli_support import CliError, finite_float, float_within, positive_float
from nni_msgs_adapter.ros.defaults import controller_defaults, plant_defaults
from nni_plant_sim.link import Link
from nni_plant_sim.model import SmibParams
from nni_plant_sim.scenarios import SCENARIO_FIELDS, SCENARIOS, from_values

#: The paper's battery limits b, pu: the default --b of ``nni-simulate`` and ``nni-demo``.
PAPER_BATTERY_LIMITS = (0.0, 0.2, 0.3, math.inf)


def positive_or_inf(text: str) -> float:
    """argparse type: a number > 0, or ``inf`` (for good)."""
    if text.strip().lower() in ("inf", ".inf"):
        return math.inf
    return positive_float(text)


@dataclass(frozen=True)
class Option:
    """One command-line option and the node parameter it sets."""

    flag: str
    node: str  # "plant" or "controller"
    name: str  # the node parameter
    kind: object  # argparse type
    text: str
    scenario: str | None = None  # the scenario it belongs to (None: any)


OPTIONS = (
    Option("--delta0", "plant", "delta0_rad", finite_float, "delta(0), rad", "initial_angle"),
    Option("--speed0", "plant", "speed0_rad_s", finite_float, "delta'(0), rad/s", "initial_angle"),
    Option("--step-p-mech", "plant", "step_p_mech_pu", finite_float, "P_M during the step, pu", "mechanical_step"),
    Option("--step-duration", "plant", "step_duration_s", positive_or_inf,
           "length of the step, s ('inf': for good, which moves the equilibrium)", "mechanical_step"),
    Option("--fault-p-max", "plant", "fault_p_max_pu", finite_float, "P_max during the fault, pu",
           "transfer_limit_fault"),
    Option("--clearing-time", "plant", "clearing_time_s", positive_float, "clearing time, s", "transfer_limit_fault"),
    Option("--H", "plant", "inertia_h_s", finite_float, "inertia constant H, s"),
    Option("--D", "plant", "damping_pu", finite_float, "damping D, pu/(rad/s)"),
    Option("--P-M", "plant", "p_mech_pu", finite_float, "mechanical power P_M, pu"),
    Option("--P-max", "plant", "p_max_pu", finite_float, "maximum transfer P_max, pu"),
    Option("--f0", "plant", "f0_hz", finite_float, "nominal frequency f0, Hz"),
    Option("--tau", "controller", "tau_s", finite_float, "phase-lead time constant tau, s"),
    Option("--K", "controller", "gain_k", finite_float, "gain K, pu/rad"),
    Option("--L", "controller", "gain_l", finite_float, "gain L, pu/rad (K < L)"),
    Option("--alpha", "controller", "alpha", finite_float, "saturated-mode decay factor alpha"),
)
#: The controller's model of the plant: node parameters of the controller that must equal the plant's here.
CONTROLLER_MODEL_KEYS = ("p_mech_pu", "p_max_pu", "inertia_h_s", "f0_hz")


def _shown(value) -> str:
    """A default as --help shows it: numbers in %g, inf as 'inf'."""
    if isinstance(value, float):
        return "inf" if math.isinf(value) else f"{value:g}"
    return str(value)


def add_model_options(parser: argparse.ArgumentParser) -> None:
    """Add --scenario, its options, the plant model, the gains and --params-file to ``parser``.

    Every option's default is None on the parser (so that an option the user
    gave can be told from one they did not) and shown in its help text.
    """
    plant, ctrl = plant_defaults(), controller_defaults()
    defaults = {"plant": plant, "controller": ctrl}
    parser.add_argument("--params-file", type=Path, metavar="YAML",
                        help="ROS params file in the nodes' format (/**/plant, /**/controller sections; e.g. a "
                             "copy of the package config files): its values replace the defaults shown here, "
                             "command-line options replace its values")
    scenario = parser.add_argument_group("scenario (what happens at t = 0)")
    scenario.add_argument("--scenario", choices=tuple(SCENARIOS), default=None,
                          help=f"default: {plant['scenario']} (initial_angle: the paper's case, the fault has moved "
                               f"the rotor and cleared; mechanical_step: P_M steps for a while; "
                               f"transfer_limit_fault: P_max drops until the fault clears)")
    groups = {None: parser.add_argument_group("plant (per unit)"),
              "controller": parser.add_argument_group("controller gains")}
    for option in OPTIONS:
        group = scenario if option.scenario else groups["controller" if option.node == "controller" else None]
        where = f"{option.scenario}: " if option.scenario else ""
        group.add_argument(option.flag, dest=option.name, type=option.kind, default=None,
                           metavar=option.flag.lstrip("-").upper().replace("-", "_"),
                           help=f"{where}{option.text} (default: {_shown(defaults[option.node][option.name])})")


@dataclass(frozen=True)
class ModelValues:
    """The resolved values, keyed by node parameter name, of the plant and the controller."""

    plant: dict
    controller: dict

    @property
    def scenario_name(self) -> str:
        return self.plant["scenario"]

    def smib(self) -> SmibParams:
        """The plant model (ValueError naming a bad value)."""
        p = self.plant
        return SmibParams(p["inertia_h_s"], p["damping_pu"], p["p_mech_pu"], p["p_max_pu"], p["f0_hz"])

    def controller_params(self, b: float) -> ControllerParams:
        """The controller's design for battery limit ``b`` (ValueError naming a bad value)."""
        c = self.controller
        return ControllerParams(c["tau_s"], c["gain_k"], c["gain_l"], c["alpha"], b)

    def validate(self) -> None:
        """ValueError naming the first bad value of the plant, the gains or the scenario."""
        self.smib()
        self.controller_params(math.inf)
        self.scenario()

    def scenario(self):
        """The scenario object (:func:`nni_plant_sim.scenarios.from_values`)."""
        return from_values(self.plant)

    def scenario_values(self) -> dict:
        """``{"name": ..., <the scenario's own values>}``."""
        return {"name": self.scenario_name, **{k: self.plant[k] for k in SCENARIO_FIELDS[self.scenario_name]}}

    def plant_node_parameters(self) -> dict:
        """What the plant node must be given to run this model and scenario."""
        keys = ("scenario", *SCENARIO_FIELDS[self.scenario_name],
                *(o.name for o in OPTIONS if o.node == "plant" and not o.scenario))
        return {k: self.plant[k] for k in keys}

    def controller_node_parameters(self) -> dict:
        """What the controller node must be given: its gains and its model of the plant (the plant's values)."""
        return {**{o.name: self.controller[o.name] for o in OPTIONS if o.node == "controller"},
                **{k: self.plant[k] for k in CONTROLLER_MODEL_KEYS}}

    def header(self) -> str:
        """One line naming the scenario and its values, the plant and the gains."""
        p, c = self.plant, self.controller
        name = self.scenario_name
        if name == "initial_angle":
            what = f"delta(0) = {p['delta0_rad']:g} rad, delta'(0) = {p['speed0_rad_s']:g} rad/s"
        elif name == "mechanical_step":
            length = ("for good: the equilibrium moves" if math.isinf(p["step_duration_s"])
                      else f"for {p['step_duration_s']:g} s")
            what = f"P_M = {p['step_p_mech_pu']:g} pu {length}"
        else:
            what = f"P_max = {p['fault_p_max_pu']:g} pu until cleared at {p['clearing_time_s']:g} s"
        return (f"{name} ({what}); H {p['inertia_h_s']:g} s, D {p['damping_pu']:g}, P_M {p['p_mech_pu']:g}, "
                f"P_max {p['p_max_pu']:g}, f0 {p['f0_hz']:g} Hz; tau {c['tau_s']:g} s, K {c['gain_k']:g}, "
                f"L {c['gain_l']:g}, alpha {c['alpha']:g}")


def _params_file_values(path: Path, prog: str) -> dict:
    """``{"plant": {...}, "controller": {...}}`` from a ROS params file, checked key by key."""
    try:
        with open(path) as handle:
            content = yaml.safe_load(handle)
    except yaml.YAMLError as exc:
        raise CliError(f"--params-file {path}: not YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(content, dict):
        raise CliError(f"--params-file {path}: expected node sections such as '/**/plant:'")
    known = {"plant": plant_defaults(), "controller": controller_defaults()}
    settable = {"plant": {"scenario", *(n for f in SCENARIO_FIELDS.values() for n in f),
                          *(o.name for o in OPTIONS if o.node == "plant")},
                "controller": {*(o.name for o in OPTIONS if o.node == "controller"), *CONTROLLER_MODEL_KEYS}}
    found = {"plant": {}, "controller": {}}
    for key, section in content.items():
        node = str(key).rstrip("/").rsplit("/", 1)[-1]
        parameters = section.get("ros__parameters") if isinstance(section, dict) else None
        if node not in found or not isinstance(parameters, dict):
            raise CliError(f"--params-file {path}: section {key!r} is not '/**/plant' or '/**/controller' "
                           f"with ros__parameters")
        for name, value in parameters.items():
            if name not in known[node]:
                raise CliError(f"--params-file {path}: {node} has no parameter {name!r}")
            if name not in settable[node]:
                raise CliError(f"--params-file {path}: {node}.{name} does not apply to {prog} "
                               f"(it takes the scenario, plant model and gains; see --help for the rest)")
            expected = str if name == "scenario" else float
            if isinstance(value, bool) or not isinstance(value, (int, float) if expected is float else str):
                raise CliError(f"--params-file {path}: {node}.{name} must be a "
                               f"{'string' if expected is str else 'number'}, got {value!r}")
            found[node][name] = expected(value)
    return found


def resolve_model(args: argparse.Namespace, prog: str) -> ModelValues:
    """The values the options describe (defaults < --params-file < command line), checked.

    CliError (one line) for a command-line option that does not apply to the
    chosen scenario, for a bad params file, or for a controller model in the
    file that differs from the plant (this study models the controller with
    the plant's own values).
    """
    plant, controller = plant_defaults(), controller_defaults()
    if args.params_file is not None:
        from_file = _params_file_values(args.params_file, prog)
        plant.update(from_file["plant"])
        controller.update(from_file["controller"])
        for name in CONTROLLER_MODEL_KEYS:
            if name in from_file["controller"] and controller[name] != float(plant[name]):
                raise CliError(f"--params-file {args.params_file}: controller.{name} = {controller[name]:g} "
                               f"differs from the plant's {plant[name]:g}; {prog} models the controller with "
                               f"the plant's own values")
    if args.scenario is not None:
        plant["scenario"] = args.scenario
    if plant["scenario"] not in SCENARIOS:
        raise CliError(f"scenario must be one of {', '.join(SCENARIOS)}, got {plant['scenario']!r}")
    for option in OPTIONS:
        value = getattr(args, option.name)
        if value is None:
            continue
        if option.scenario and option.scenario != plant["scenario"]:
            raise CliError(f"{option.flag} applies to --scenario {option.scenario}, not {plant['scenario']}")
        (plant if option.node == "plant" else controller)[option.name] = value
    for name in CONTROLLER_MODEL_KEYS:
        controller[name] = plant[name]
    return ModelValues(plant, controller)



#: The link options of ``nni-simulate`` (SMIB and ``--case``); they model the plant nodes' link_* parameters.
LINK_OPTIONS = ("link_delay", "link_jitter", "link_loss", "link_seed")


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value < 2**31:
        raise argparse.ArgumentTypeError(f"expected an integer 0..{2**31 - 1}, got {text!r}")
    return value


def add_link_options(parser: argparse.ArgumentParser) -> None:
    """--link-delay/--link-jitter/--link-loss/--link-seed (None when not given, so that one that does not apply is refused)."""
    group = parser.add_argument_group(
        "communication link (the plant nodes' link_* parameters): the answer to measurement k takes effect at "
        "t_k + delay + jitter u_k (u_k uniform in [0, 1), seeded by (seed, generator, k)), or is lost with the "
        "given probability and the command in force stays")
    group.add_argument("--link-delay", type=float_within(0.0, 10.0, "s"), metavar="S",
                       help="fixed measurement-to-command delay, s (default 0)")
    group.add_argument("--link-jitter", type=float_within(0.0, 10.0, "s"), metavar="S",
                       help="extra delay uniform in [0, S), s (default 0)")
    group.add_argument("--link-loss", type=float_within(0.0, 1.0, "(a probability)"), metavar="P",
                       help="probability that an answer is lost (default 0)")
    group.add_argument("--link-seed", type=_seed, metavar="N", help="seed of the jitter and loss draws (default 0)")


def given_link_options(args: argparse.Namespace) -> list[str]:
    """The link options given on the command line, as typed (``--link-delay``)."""
    return [f"--{name.replace('_', '-')}" for name in LINK_OPTIONS if getattr(args, name) is not None]


def link_of(args: argparse.Namespace) -> Link:
    """The Link the options describe (defaults: none)."""
    return Link(args.link_delay or 0.0, args.link_jitter or 0.0, args.link_loss or 0.0, args.link_seed or 0)
