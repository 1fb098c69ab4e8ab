"""Declaring and validating node parameters, shared by the plant and controller nodes.

Each parameter is declared once with its type, default, description (with unit)
and range; the node's own validation (a dataclass constructor raising ValueError
that names the violated condition) runs on start-up and on every runtime change,
and an invalid change is rejected with that reason, the old values kept. While
a run is active the safety-relevant parameters are locked (:func:`locked_changes`).
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


def install_validation(node, specs, prepare, install) -> None:
    """Validate every runtime change with ``prepare(new_values)``; apply it with ``install`` once it is set.

    ``prepare`` builds the node's configuration from the full value dict,
    raising ValueError (message = reason) to reject the change, and changes
    nothing; the on-set callback only calls it. rclpy's post-set callback then
    hands what it built to ``install``, so nothing is installed for a rejected
    change and the old values stay.
    """
    names = {spec.name for spec in specs}
    prepared = []

    def on_set(parameters):
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


def locked_changes(old: dict, new: dict, locked, when: str = "while a run is active (safety lockdown)") -> None:
    """ValueError naming the parameters among ``locked`` whose values differ between ``old`` and ``new``."""
    changed = sorted(name for name in locked if old.get(name) != new.get(name))
    if changed:
        raise ValueError(f"{', '.join(changed)} cannot change {when}")
