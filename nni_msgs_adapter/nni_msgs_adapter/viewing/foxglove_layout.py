"""Foxglove layouts of the loop: the paper's plots as Foxglove panels, for one generator or a network (issue 34).

    python -m nni_msgs_adapter.viewing.foxglove_layout docs/foxglove/nni_smib.json
    python -m nni_msgs_adapter.viewing.foxglove_layout --generators 4 docs/foxglove/nni_kundur_two_area.json

A layout is what Foxglove's "Import from file..." reads (its export format): ``configById`` (each panel's
settings, keyed ``<PanelType>!<id>``), ``layout`` (the mosaic tree of panel ids), ``globalVariables``,
``userNodes``, ``playbackConfig``. The panels name the topics and fields of the message contract
(:mod:`nni_msgs_adapter.ros.contract`), with Foxglove's message path syntax (``/pmu.position[0]``,
``.@negative``), plotted against each message's header stamp (simulated time in lockstep, as the recording's).
The same layout opens a recording and the live stream of ``nni-demo --foxglove`` (the topics are the same).

What Foxglove's panels cannot compute, they do not show: the paper plots the frequency deviation in Hz and the
angle deviation delta - delta_bar; here the speed deviation is in rad/s (omega - omega0 = 2 pi f_dev), the
angle deviation is the controller's ``angle_dev`` (the d its law used, from the measurements), and the phase
portrait is the true (delta, omega - omega0) of ``plant/state``, delta absolute; the invariant set Omega,
drawn in deviation coordinates, is a panel of its own.
"""

from __future__ import annotations

import sys

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.cli_support import OneLineParser, writable_output, write_json

#: ``controller/state`` signal -> its index in ``position``.
SIGNAL = {name: index for index, name in enumerate(contract.CONTROLLER_SIGNALS)}


def _topic(namespace: str, name: str) -> str:
    return "/" + "/".join(filter(None, (namespace.strip("/"), name.strip("/"))))


def _series(path: str, label: str) -> dict:
    return {"value": path, "enabled": True, "timestampMethod": "headerStamp", "label": label}


def plot(title: str, series: list[dict], x_path: str | None = None) -> dict:
    """A Plot panel's settings: time series against the header stamp, or (``x_path``) y against x."""
    config = {"title": title, "paths": series, "showLegend": True, "legendDisplay": "floating",
              "showXAxisLabels": True, "showYAxisLabels": True, "isSynced": x_path is None,
              "xAxisVal": "timestamp" if x_path is None else "custom"}
    if x_path is not None:
        config["xAxisPath"] = {"value": x_path, "enabled": True}
    return config


def generator_panels(namespace: str = "", label: str = "") -> dict:
    """The paper's plots of one generator's loop (its topics under ``namespace``): panel id -> settings; the
    invariant set for the SMIB only (the network plant publishes none)."""
    pmu, state = _topic(namespace, contract.TOPIC_PMU), _topic(namespace, contract.TOPIC_PLANT_STATE)
    controller, command = _topic(namespace, contract.TOPIC_CONTROLLER_STATE), _topic(namespace,
                                                                                       contract.TOPIC_BATTERY_COMMAND)
    omega = _topic(namespace, contract.TOPIC_INVARIANT_SET)
    tag = f"{label} " if label else ""
    key = namespace.strip("/") or "smib"
    limit = f"{controller}.position[{SIGNAL['battery_limit']}]"
    panels = {
        f"Plot!{key}_angle": plot(f"{tag}angle deviation d (rad)", [
            _series(f"{controller}.position[{SIGNAL['angle_dev']}]", "d, the law's (from the PMU)")]),
        f"Plot!{key}_speed": plot(f"{tag}speed deviation omega - omega0 (rad/s; 2 pi x frequency deviation)", [
            _series(f"{state}.velocity[0]", "true"), _series(f"{pmu}.velocity[0]", "PMU")]),
        f"Plot!{key}_battery": plot(f"{tag}battery power P_ST (pu) and its limits +-b", [
            _series(f"{command}.effort[0]", "commanded"), _series(f"{state}.effort[0]", "applied (plant)"),
            _series(limit, "+b"), _series(f"{limit}.@negative", "-b")]),
        f"Plot!{key}_saturation": plot(f"{tag}saturation (1: the command is at +-b) and W_hat (pu rad)", [
            _series(f"{controller}.position[{SIGNAL['saturated']}]", "saturated"),
            _series(f"{controller}.position[{SIGNAL['w_hat']}]", "W_hat")]),
        f"Plot!{key}_portrait": plot(f"{tag}phase portrait: omega - omega0 (rad/s) against delta (rad)", [
            _series(f"{state}.velocity[0]", "trajectory")], x_path=f"{state}.position[0]"),
    }
    if not namespace:
        panels["Plot!smib_omega"] = plot("invariant set Omega (speed rad/s against angle deviation rad)", [
            _series(f"{omega}.polygon.points[:].y", "boundary of Omega")], x_path=f"{omega}.polygon.points[:].x")
    return panels


def network_panels(namespaces) -> dict:
    """Every generator's angle deviation (its controller's d: against the COI with ``--reference coi``) and
    battery power, one series per generator, and each generator's speed deviation."""
    def each(topic: str, field: str) -> list[dict]:
        return [_series(f"{_topic(ns, topic)}.{field}", ns.strip("/")) for ns in namespaces]

    return {
        "Plot!network_angle": plot("every generator's angle deviation d (rad; against the COI with --reference coi)",
                                   each(contract.TOPIC_CONTROLLER_STATE, f"position[{SIGNAL['angle_dev']}]")),
        "Plot!network_speed": plot("every generator's speed deviation omega - omega0 (rad/s)",
                                   each(contract.TOPIC_PLANT_STATE, "velocity[0]")),
        "Plot!network_battery": plot("every battery's power P_ST (pu of its machine, as commanded)",
                                     each(contract.TOPIC_BATTERY_COMMAND, "effort[0]")),
        "Plot!network_saturation": plot("every battery at its limit (1: saturated)",
                                        each(contract.TOPIC_CONTROLLER_STATE, f"position[{SIGNAL['saturated']}]")),
    }


def _common_panels() -> dict:
    return {"DiagnosticSummary!loop": {"topicToRender": contract.TOPIC_DIAGNOSTICS, "pinnedIds": [],
                                       "hardwareIdFilter": "", "sortByLevel": True},
            "RawMessages!run": {"topicPath": "/nni/run", "diffEnabled": False, "diffMethod": "custom",
                                "diffTopicPath": "", "showFullMessageForDiff": False}}


def _mosaic(ids: list[str], direction: str = "row"):
    """A balanced mosaic tree of ``ids`` (Foxglove's ``layout``), alternating split directions."""
    if len(ids) == 1:
        return ids[0]
    half = (len(ids) + 1) // 2
    other = "column" if direction == "row" else "row"
    return {"direction": direction, "first": _mosaic(ids[:half], other), "second": _mosaic(ids[half:], other),
            "splitPercentage": round(100 * half / len(ids), 3)}


def layout(generators: int = 0) -> dict:
    """The SMIB layout (``generators`` 0: topics at the root) or a network's (``/gen1`` .. ``/gen<n>``:
    every generator together, then generator 1's paper plots)."""
    if generators < 0:
        raise ValueError("generators must be 0 (the SMIB) or a positive count")
    if generators == 0:
        panels = {**generator_panels(), **_common_panels()}
    else:
        spaces = [f"gen{k}" for k in range(1, generators + 1)]
        panels = {**network_panels(spaces), **generator_panels("gen1", "gen1:"), **_common_panels()}
    return {"configById": panels, "globalVariables": {}, "userNodes": {},
            "playbackConfig": {"speed": 1.0}, "layout": _mosaic(list(panels))}


def main(argv=None) -> int:
    parser = OneLineParser(prog="python -m nni_msgs_adapter.viewing.foxglove_layout",
                           description="Write a Foxglove layout of the loop (Foxglove: Layouts > Import from file).")
    parser.add_argument("output", type=writable_output, help="the layout JSON file to write")
    parser.add_argument("--generators", type=int, default=0,
                        help="a network's generator count (/gen1 .. /gen<N>); default 0: the SMIB")
    args = parser.parse_args(argv)
    if args.generators < 0:
        parser.error("--generators must be 0 (the SMIB) or a positive count")
    write_json(args.output, layout(args.generators))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
