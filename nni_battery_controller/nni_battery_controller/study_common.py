"""What the SMIB study (``nni-simulate``) and the network study (``nni-simulate --case``) share.

The delay margin search's options (the span and step of its scan, and the
options it refuses beside it), the lines above its table and its rows; the
``link`` entry of a JSON summary; the project's version. Pure python: no ROS import.
"""

from __future__ import annotations

from importlib import metadata

from nni_battery_controller.margins import DELAY_MARGIN_TOLERANCE_S, DELAY_SCAN_STEP_S
from nni_msgs_adapter.ros.cli_support import CliError
from nni_plant_sim.link import Link

#: --delay-max when not given, s.
DEFAULT_DELAY_MAX_S = 1.0


def refuse_beside_delay_margin(args, flags) -> None:
    """CliError for the first option of ``flags`` (argparse dests) given with --delay-margin."""
    for flag in flags:
        if getattr(args, flag):
            raise CliError(f"--delay-margin searches the link's fixed delay and prints a table (and --json): "
                           f"it takes no --{flag.replace('_', '-')}")


def resolve_delay_span(args) -> None:
    """--delay-max and --delay-step: with --delay-margin their defaults filled, else refused when given.

    CliError for a step longer than the span, or for either option without --delay-margin.
    """
    if not args.delay_margin:
        for flag in ("delay_max", "delay_step"):
            if getattr(args, flag) is not None:
                raise CliError(f"--{flag.replace('_', '-')} applies to --delay-margin only")
        return
    args.delay_max = DEFAULT_DELAY_MAX_S if args.delay_max is None else args.delay_max
    args.delay_step = DELAY_SCAN_STEP_S if args.delay_step is None else args.delay_step
    if args.delay_step > args.delay_max:
        raise CliError(f"--delay-step {args.delay_step:g} s is longer than --delay-max {args.delay_max:g} s")


def delay_search_lines(scan_s: float, upper_s: float, link: Link, prefix: str = "") -> list[str]:
    """The lines above a delay margin table: how it was searched, the link besides the delay, the header.

    ``prefix``: the header of the columns before b (as :func:`delay_margin_row`'s).
    """
    lines = [f"scan from 0 in steps of {scan_s * 1e3:g} ms (--delay-step) up to {upper_s:g} s (--delay-max) until a "
             f"run slips, then bisection to {DELAY_MARGIN_TOLERANCE_S * 1e3:g} ms; the margin is the first loss "
             f"(a longer delay may be in synchronism again)"]
    if link.active:
        lines.append(f"on top of the delay: {link.describe()}")
    return lines + [f"{prefix}{'b (pu)':>7} {'margin (ms)':>12} {'slips at (ms)':>14} {'runs':>5}  result"]


def delay_margin_row(result, prefix: str = "") -> str:
    """One row of the delay margin table (``prefix``: columns before b)."""
    margin = "-" if result.margin_s is None or result.slips_s is None else f"{result.margin_s * 1e3:.1f}"
    slips = "-" if result.slips_s is None else f"{result.slips_s * 1e3:.1f}"
    return f"{prefix}{result.b:>7g} {margin:>12} {slips:>14} {result.runs:>5}  {result.text()}"


def link_json(link: Link, delay_searched: bool = False) -> dict:
    """``{"link": ...}`` of a JSON summary: the link's values (its delay ``"searched"`` by --delay-margin).

    Nothing for a run without a link and without a search, so that its JSON is as without the link options.
    """
    if delay_searched:
        return {"link": link.to_json() | {"delay_s": "searched"}}
    return {"link": link.to_json()} if link.active else {}


def software_version() -> str:
    """Version of the installed nni_battery_controller package."""
    try:
        return metadata.version("nni_battery_controller")
    except metadata.PackageNotFoundError:
        return "unknown"
