"""Rerun bridge node: streams a running loop to Rerun with the project's blueprint.

Subscribes to ``plant/state`` (speed deviation), ``controller/state`` (angle
deviation, battery power, saturation, W_hat, b) and the latched
``plant/invariant_set``; pairs them by stamp (both carry the measurement's stamp)
and logs each sample through :class:`nni_msgs_adapter.viewing.rerun_live.LiveLogger`.
A separate process, off the control path: a slow viewer never delays a command.

Runs. Once a plant's ``plant/state`` and a controller's ``controller/state``
publishers have matched, the bridge also subscribes to ``pmu``, the topic whose
subscribers the plant counts (``wait_for_subscribers``): a plant told to wait
for the bridge therefore starts only when the bridge hears both. That
subscription is dropped when the plant goes, and made again for the next run.
Each run is labelled by its battery limit ("b=0.3"; "b=0.3 #2" for a second run
with the same b) and drawn on its simulated time axis: t = 0 at the run's first
``plant/state`` (its start, when the bridge was counted; lockstep stamps are
simulated time already). All runs go into one recording, so they overlay.

Progress: whenever a run's count of logged samples changes, one line
``rerun bridge run: {"run": i, "label": ..., "samples": n, "first_t_s": ...,
"last_t_s": ...}`` on stdout (``PROGRESS_PREFIX``), so that nni-demo can check
that the stream holds every sample of run i before it moves on.

A network (parameter ``namespaces``, e.g. ``[/gen1, /gen2, /gen3, /gen4]``, 1-based
in case order as the network plant names them, with ``case``, the case's name the
view is labelled with, and ``coi_weights``, the machines' inertias M in the same
order): the same topics in every namespace; a generator's sample is drawn once
every generator's ``plant/state`` of its stamp and its own ``controller/state``
are in, its angle relative to the centre of inertia (weighted by ``coi_weights``),
labelled ``gen<i>`` (``gen<i> #2`` in a second run), in the network layout
(:data:`rerun_layout.NETWORK_VIEW`); ``f0_hz`` must be the case's (the launcher
gives both: the bridge, in the message layer, does not load cases). The gate subscribes to every generator's ``pmu``. The progress line then
also holds ``"generators": {namespace: samples}``. Empty ``namespaces`` (the
default): the SMIB topics of the bridge's own namespace, as above.

``sink`` is ``save`` (to ``path``), ``serve`` (gRPC + web viewer hosted by
this process, on every network interface: the SDK has no bind address; the URL
is logged), ``connect`` (to a viewer or ``rerun --serve-web`` at ``url``; how
nni-demo serves, bound to localhost) or ``spawn`` (a native viewer, needs a
display).
"""

from __future__ import annotations

import functools
import json
import math
import sys
import time

import numpy as np
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.defaults import plant_defaults
from nni_msgs_adapter.ros.node_main import run_node
from nni_msgs_adapter.ros.ros_params import Spec, declared_values
from nni_msgs_adapter.viewing.bridge_protocol import PROGRESS_PREFIX, READY_TEXT, URL_TEXT
from nni_msgs_adapter.viewing.palette import colour_rgb, generator_colour_rgb
from nni_msgs_adapter.viewing.rerun_layout import NETWORK_VIEW, blueprint
from nni_msgs_adapter.viewing.rerun_live import LiveLogger
from nni_msgs_adapter.viewing.rerun_stream import APP_ID, open_recording


@functools.cache
def parameters() -> tuple[Spec, ...]:
    """The bridge's parameters; f0's default is the plant's (``nni_plant_sim/config/plant.yaml``, read on first use)."""
    return (
        Spec("sink", "save", "Where the stream goes.", choices=("save", "serve", "spawn", "connect"), read_only=True),
        Spec("path", "live.rrd", "Output .rrd file for sink=save.", read_only=True),
        Spec("url", "rerun+http://127.0.0.1:9876/proxy", "Viewer or server to stream to for sink=connect.",
             read_only=True),
        Spec("f0_hz", plant_defaults()["f0_hz"], "Nominal frequency, Hz (frequency deviation = speed / 2 pi); "
             "with namespaces the case's.", 1.0, 1e3, read_only=True),
        Spec("case", "", "With namespaces: the network case of the generators, the view's label (e.g. kundur_two_area).",
             read_only=True),
    )


#: The string-array parameter of a network's generator namespaces (declared apart: an empty default has no type).
NAMESPACES_PARAMETER = "namespaces"
NAMESPACES_DESCRIPTION = ("Generator namespaces of a network, case order (e.g. [/gen1, /gen2]); empty: the SMIB topics "
                          "of the bridge's own namespace. Needs case and coi_weights.")
#: The double-array parameter of the machines' inertias (declared apart, as namespaces).
WEIGHTS_PARAMETER = "coi_weights"
WEIGHTS_DESCRIPTION = "With namespaces: each generator's inertia M (any unit), case order; they weigh the centre of inertia."


def coi_weights(namespaces: list[str], case: str, weights: list[float]):
    """The normalised centre-of-inertia weights of a bridge watching ``namespaces``; None for the SMIB
    (ValueError, one line, if the parameters disagree)."""
    if not namespaces:
        if case or weights:
            raise ValueError(f"{'case' if case else 'coi_weights'} needs namespaces (the generators to show)")
        return None
    if not case or not weights:
        raise ValueError("namespaces needs case (the view's label) and coi_weights (the machines' inertias weigh "
                         "the centre of inertia)")
    expected = [f"/gen{i + 1}" for i in range(len(namespaces))]
    if list(namespaces) != expected:
        raise ValueError(f"namespaces are {expected[:3]} ... in case order (the network plant's), got {list(namespaces)}")
    values = np.asarray(weights, dtype=float)
    if len(values) != len(namespaces):
        raise ValueError(f"coi_weights has {len(values)} values for {len(namespaces)} namespaces")
    if not (np.isfinite(values).all() and (values > 0).all()):
        raise ValueError(f"coi_weights must be positive and finite, got {list(weights)}")
    return values / values.sum()


#: How often the bridge looks for a plant and a controller, and reports progress, s.
WATCH_PERIOD_S = 0.05

#: A plant counts as gone once no plant/state writer is matched and none of its states came for this long, s
#: (under load a live plant's writer count was once read as 0 mid-run, which split the run in two).
PLANT_GONE_S = 0.5

#: The gate opens once a plant and every controller have been heard this long, s: their writers then
#: have matched the bridge's readers too (discovery is not symmetric in time; without it a controller's
#: first state once went out before its writer knew the bridge, and the stream missed that sample).
GATE_SETTLE_S = 1.0

#: Plant states kept while waiting for the controller state of the same stamp.
_PENDING_LIMIT = 1000


def run_label(battery_limit_pu: float) -> str:
    """Label of a run in the views: b=0.3, b=inf."""
    return "b=inf" if math.isinf(battery_limit_pu) else f"b={battery_limit_pu:g}"


class _Run:
    """One run as the bridge sees it: its start stamp, its loggers (one per generator) and what was logged."""

    def __init__(self, index: int):
        self.index = index
        self.t0_ns: int | None = None   # stamp of the run's first plant/state
        self.loggers: dict[int, LiveLogger] = {}  # generator index -> its logger
        self.label = ""
        self.samples = 0
        self.generator_samples: dict[str, int] = {}
        self.first_t_s = self.last_t_s = math.nan
        self.reported = 0
        self.plant_gone = False

    def progress(self) -> str:
        report = {"run": self.index, "label": self.label, "samples": self.samples,
                  "first_t_s": self.first_t_s, "last_t_s": self.last_t_s}
        if self.generator_samples:
            report["generators"] = self.generator_samples
        return PROGRESS_PREFIX + json.dumps(report)

    def logged(self, t_s: float, namespace: str | None) -> None:
        self.samples += 1
        if namespace is not None:
            self.generator_samples[namespace] = self.generator_samples.get(namespace, 0) + 1
        self.first_t_s = t_s if self.samples == 1 else self.first_t_s
        self.last_t_s = t_s


class RerunBridge(Node):
    """Pairs plant and controller states by stamp and logs them live, one run after another."""

    def __init__(self, **kwargs):
        super().__init__("rerun_bridge", **kwargs)
        values = declared_values(self, parameters())
        self.declare_parameter(NAMESPACES_PARAMETER, Parameter.Type.STRING_ARRAY,
                               ParameterDescriptor(description=NAMESPACES_DESCRIPTION, read_only=True))
        self.declare_parameter(WEIGHTS_PARAMETER, Parameter.Type.DOUBLE_ARRAY,
                               ParameterDescriptor(description=WEIGHTS_DESCRIPTION, read_only=True))
        namespaces = self.get_parameter_or(NAMESPACES_PARAMETER).value or []
        self._weights = coi_weights(namespaces, values["case"], list(self.get_parameter_or(WEIGHTS_PARAMETER).value or []))
        self._network = self._weights is not None  # a network's generators
        self._namespaces = tuple(namespaces) or ("",)
        self._f0_hz, self._case = values["f0_hz"], values["case"]
        sink = (values["sink"], {"save": values["path"], "connect": values["url"]}.get(values["sink"]))
        layout = blueprint(kind=NETWORK_VIEW) if self._network else None
        self._recording, url = open_recording(APP_ID, sink, layout=layout)
        if url:
            self.get_logger().info(f"{URL_TEXT} {url}")
        self._boundary = None
        self._run: _Run | None = None
        self._runs = 0
        self._labels: dict[str, int] = {}  # label -> runs drawn with it
        self._gates = []                    # pmu subscriptions while a run may start: what the plant counts
        # stamp -> the halves that arrived: "plant" {generator: (angle, speed)}, "controller" {generator: signals},
        # and "logged", the generators drawn at that stamp
        self._pending: dict[int, dict] = {}
        self._plant_subs, self._controller_subs = [], []
        for index, namespace in enumerate(self._namespaces):
            self._plant_subs.append(self._subscribe(namespace, contract.TOPIC_PLANT_STATE,
                                                    lambda msg, i=index: self._on_plant(i, msg)))
            self._controller_subs.append(self._subscribe(namespace, contract.TOPIC_CONTROLLER_STATE,
                                                         lambda msg, i=index: self._on_controller(i, msg)))
        if not self._network:
            self._subscribe("", contract.TOPIC_INVARIANT_SET, self._on_invariant_set)
        self._last_plant_s, self._heard_since = -math.inf, None
        self.create_timer(WATCH_PERIOD_S, self._watch)
        self.get_logger().info(f"{READY_TEXT} ({values['sink']})")

    def _subscribe(self, namespace: str, topic: str, callback):
        msg_type, name, qos = contract.recorder_endpoint(topic)
        return self.create_subscription(msg_type, f"{namespace}/{name}" if namespace else name, callback, qos)

    def _watch(self) -> None:
        """Open the gate when a plant and every controller are heard; close it when the plant is gone."""
        plants = self._plant_subs[0].get_publisher_count()
        controllers = all(sub.get_publisher_count() for sub in self._controller_subs)
        heard = plants and controllers
        self._heard_since = (self._heard_since or time.monotonic()) if heard else None
        if not self._gates and heard and self._run_over() and time.monotonic() - self._heard_since >= GATE_SETTLE_S:
            self._begin_run()
        elif self._gates and not plants and time.monotonic() - self._last_plant_s > PLANT_GONE_S:
            self._end_plant()
        self._report()

    def _run_over(self) -> bool:
        return self._run is None or self._run.plant_gone

    def _begin_run(self) -> None:
        """A new run: the previous one's halves are forgotten, and the gate opens unless it is open."""
        self._runs += 1
        self._run = _Run(self._runs)
        self._pending.clear()
        if not self._gates:
            self._gates = [self._subscribe(namespace, contract.TOPIC_PMU, lambda msg: None)
                           for namespace in self._namespaces]

    def _end_plant(self) -> None:
        """The run's plant is gone: close the gate (the next plant waits for the bridge again) and flush.

        The run stays current until the next one begins, so that its last controller states,
        still on their way when the plant left, are paired and drawn.
        """
        for gate in self._gates:
            self.destroy_subscription(gate)
        self._gates = []
        self._run.plant_gone = True
        self._flush()

    def _flush(self) -> None:
        if self._run is not None:
            for logger in self._run.loggers.values():
                logger.flush()
        self._recording.flush()

    def _report(self) -> None:
        run = self._run
        if run is not None and run.samples != run.reported:
            print(run.progress(), flush=True)
            run.reported = run.samples

    def _on_invariant_set(self, msg) -> None:
        self._boundary = np.array([(p.x, p.y) for p in msg.polygon.points])

    def _on_plant(self, index: int, msg) -> None:
        self._last_plant_s = time.monotonic()
        stamp_ns, delta, speed, _ = contract.plant_state_from_message(msg)
        if self._run_over():  # a plant that did not wait for the bridge: its run starts here
            self._begin_run()
        if self._run.t0_ns is None:
            self._run.t0_ns = stamp_ns
        self._pair(stamp_ns, "plant", index, (delta, speed))

    def _on_controller(self, index: int, msg) -> None:
        stamp_ns, signals = contract.controller_state_from_message(msg)
        self._pair(stamp_ns, "controller", index, signals)

    def _pair(self, stamp_ns: int, half: str, index: int, value) -> None:
        """Log each generator's sample once its controller state and every generator's plant state are in."""
        sample = self._pending.setdefault(stamp_ns, {"plant": {}, "controller": {}, "logged": set()})
        sample[half][index] = value
        size = len(self._namespaces)
        if len(sample["plant"]) < size or not sample["controller"] or self._run is None or self._run.t0_ns is None:
            if len(self._pending) > _PENDING_LIMIT:  # a half that never came: forget the oldest
                self._pending.pop(next(iter(self._pending)))
            return
        angles = np.array([sample["plant"][i][0] for i in range(size)])
        if self._network:
            angles = angles - float(np.dot(self._weights, angles))
        t_s = (stamp_ns - self._run.t0_ns) / 1e9  # correctly rounded: 0.98, not 0.9800000000000001
        for i, signals in sample["controller"].items():
            if i not in sample["logged"]:
                self._log(i, t_s, angles[i], sample["plant"][i][1], signals)
                sample["logged"].add(i)
        if len(sample["logged"]) == size:
            del self._pending[stamp_ns]

    def _log(self, index: int, t_s: float, angle_rad: float, speed: float, signals: dict) -> None:
        """One generator's sample: the SMIB's angle deviation, or a network generator's angle to the COI."""
        run = self._run
        network = self._network
        if index not in run.loggers:
            b = signals["battery_limit"]
            label = self._namespaces[index].lstrip("/") if network else run_label(b)
            self._labels[label] = self._labels.get(label, 0) + 1
            label = label if self._labels[label] == 1 else f"{label} #{self._labels[label]}"
            run.label = run.label or (self._case if network else label)
            run.loggers[index] = (
                LiveLogger(self._recording, label, b, self._f0_hz, color=generator_colour_rgb(index), kind=NETWORK_VIEW)
                if network else
                LiveLogger(self._recording, label, b, self._f0_hz, omega_boundary=self._boundary, color=colour_rgb(b)))
        run.loggers[index].log(t_s, angle_rad if network else signals["angle_dev"], speed, signals["battery_power"],
                               signals["saturated"] > 0.5, None if network else signals["w_hat"])
        run.logged(t_s, self._namespaces[index] if network else None)

    def close(self) -> None:
        """Draw what is pending, report and flush the stream."""
        self._flush()
        self._report()


def main(args=None) -> int:
    """``ros2 run nni_msgs_adapter rerun_bridge``."""
    return run_node(RerunBridge, args, prog="rerun_bridge")


if __name__ == "__main__":
    sys.exit(main())
