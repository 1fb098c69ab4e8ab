"""Declaring and validating node parameters, shared by the plant and controller nodes.

Each parameter is declared once with its type, default, description (with unit)
and range; the node's own validation (a dataclass constructor raising ValueError
that names the violated condition) runs on start-up.

From the start, no parameter can be changed over the parameter services (by
any process: limits, gains, model, reference, noise, link, and rclpy's own
``use_sim_time``); reading them stays possible. A node started with
``allow_tuning:=true`` (read-only: only at start) takes changes again: each one
validated, an invalid one rejected with the reason and the old values kept,
and while a run is active the safety-relevant parameters locked
(:func:`locked_changes`). :func:`effective_values` are what a node states at
start (``node_main`` prints them, the demo and the launch files compare).
"""

from __future__ import annotations

from dataclasses import dataclass

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult


@dataclass(frozen=True)
class Spec:
    """One parameter: name, default (its type is the parameter's), description, range.

    ``array_of`` (``str``, ``float`` or ``int``) makes it a string, double or integer array, whose default may be empty.
    """

    name: str
    default: object
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False
    array_of: type | None = None

    def descriptor(self) -> ParameterDescriptor:
        """ParameterDescriptor with the range for numbers and choices in the text."""
        text = self.description + (f" One of: {', '.join(self.choices)}." if self.choices else "")
        descriptor = ParameterDescriptor(name=self.name, description=text, read_only=self.read_only)
        if self.low is None or self.high is None or isinstance(self.default, bool):
            return descriptor
        if isinstance(self.default, int):
            descriptor.integer_range = [IntegerRange(from_value=int(self.low), to_value=int(self.high), step=0)]
        else:  # an infinite upper bound works (b may be .inf)
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(self.low), to_value=float(self.high), step=0.0)]
        return descriptor


def allow_tuning(default: bool) -> Spec:
    """The switch that opens a node's parameters to changes over the services (its default from the node's YAML)."""
    return Spec("allow_tuning", default, "Let other processes change parameters over the parameter services (each "
                "change validated; during a run the controller's gains only, nothing of the plant). false: every "
                "parameter, use_sim_time included, is locked from the start; reading stays possible.", read_only=True)


def declare(node, specs) -> None:
    """Declare every spec on ``node`` (overrides from YAML / command line apply).

    An array is declared by its type (an empty default has none rclpy could infer).
    """
    from rclpy.parameter import Parameter

    array_types = {str: Parameter.Type.STRING_ARRAY, float: Parameter.Type.DOUBLE_ARRAY, int: Parameter.Type.INTEGER_ARRAY}
    for spec in specs:
        value = array_types[spec.array_of] if spec.array_of and not spec.default else spec.default
        node.declare_parameter(spec.name, value, spec.descriptor())


def current_values(node, specs) -> dict:
    """``{name: value}`` of the declared parameters (arrays as lists, an unset one empty)."""
    from rclpy.exceptions import ParameterUninitializedException

    values = {}
    for spec in specs:
        try:
            values[spec.name] = node.get_parameter(spec.name).value
        except ParameterUninitializedException:  # an array declared by its type and never given
            values[spec.name] = []
        if spec.array_of:
            values[spec.name] = list(values[spec.name])
    return values


def declared_values(node, specs) -> dict:
    """Declare every spec on ``node`` and return the values it starts with; ValueError for one not among its choices.

    What every node does first: a value that is not among its choices stops it (one line, exit 2, from
    :mod:`.node_main`) instead of running as some other choice.
    """
    declare(node, specs)
    values = current_values(node, specs)
    check_choices(values, specs)
    return values


def check_choices(values: dict, specs) -> None:
    """ValueError naming the first parameter whose value is not among its choices."""
    for spec in specs:
        if spec.choices and values[spec.name] not in spec.choices:
            raise ValueError(f"{spec.name} must be one of {', '.join(spec.choices)}, got {values[spec.name]!r}")


def install_validation(node, specs, prepare, install, tunable: bool) -> None:
    """Refuse every runtime change, or with ``tunable`` (``allow_tuning``) validate it with ``prepare(new_values)``
    and apply it with ``install`` once it is set.

    ``prepare`` builds the node's configuration from the full value dict,
    raising ValueError (message = reason) to reject the change, and changes
    nothing; the on-set callback only calls it. rclpy's post-set callback then
    hands what it built to ``install``, so nothing is installed for a rejected
    change and the old values stay. Without ``tunable`` the request is refused
    whole, whatever it names (``use_sim_time`` and any parameter not in ``specs``
    too): rclpy calls this callback before its own (its TimeSource's), which
    never see it.
    """
    names = {spec.name for spec in specs}
    prepared = []

    def on_set(parameters):
        if not tunable:
            reason = (f"{', '.join(sorted(p.name for p in parameters))} cannot change: the node's parameters are "
                      "locked from the start (start it with allow_tuning:=true to tune them)")
            node.get_logger().warning(f"rejected parameter change: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        proposed = current_values(node, specs)
        proposed.update({p.name: p.value for p in parameters if p.name in names})
        try:
            check_choices(proposed, specs)
            prepared[:] = [prepare(proposed)]
        except ValueError as exc:
            node.get_logger().warning(f"rejected parameter change: {exc}")
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def post_set(parameters):
        if prepared:
            install(prepared.pop())

    node.add_on_set_parameters_callback(on_set)
    node.add_post_set_parameters_callback(post_set)


def effective_values(node, specs) -> dict:
    """Every parameter a node runs with: its table's (:func:`current_values`) and rclpy's ``use_sim_time``."""
    return {**current_values(node, specs), "use_sim_time": node.get_parameter("use_sim_time").value}


def locked_changes(old: dict, new: dict, locked, when: str = "while a run is active (safety lockdown)") -> None:
    """ValueError naming the parameters among ``locked`` whose values differ between ``old`` and ``new``."""
    changed = sorted(name for name in locked if old.get(name) != new.get(name))
    if changed:
        raise ValueError(f"{', '.join(changed)} cannot change {when}")
