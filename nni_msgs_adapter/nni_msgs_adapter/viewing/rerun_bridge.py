"""Rerun bridge node: streams a running loop to Rerun with the project's blueprint.

Subscribes to ``plant/state`` (speed deviation), ``controller/state`` (angle
deviation, battery power, saturation, W_hat, b) and the latched
``plant/invariant_set``; pairs them by stamp (both carry the measurement's stamp)
and logs each sample through :class:`nni_msgs_adapter.rerun_view.LiveLogger`.
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

import numpy as np
from rclpy.node import Node

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.defaults import plant_defaults
from nni_msgs_adapter.ros.node_main import run_node
from nni_msgs_adapter.ros.ros_params import Spec, check_choices, current_values, declare
from nni_msgs_adapter.viewing.palette import colour_rgb
from nni_msgs_adapter.viewing.rerun_view import APP_ID, LiveLogger, open_recording

@functools.cache
def parameters() -> tuple[Spec, ...]:
    """The bridge's parameters; f0's default is the plant's (``nni_plant_sim/config/plant.yaml``, read on first use)."""
    return (
        Spec("sink", "save", "Where the stream goes.", choices=("save", "serve", "spawn", "connect"), read_only=True),
        Spec("path", "live.rrd", "Output .rrd file for sink=save.", read_only=True),
        Spec("url", "rerun+http://127.0.0.1:9876/proxy", "Viewer or server to stream to for sink=connect.",
             read_only=True),
        Spec("f0_hz", plant_defaults()["f0_hz"], "Nominal frequency, Hz (frequency deviation = speed / 2 pi).", 1.0, 1e3, read_only=True),
    )


#: Logged once the subscriptions exist; nni-demo waits for it before the first run.
READY_TEXT = "rerun bridge ready"

#: Printed (then a JSON object) whenever a run's logged sample count changes.
PROGRESS_PREFIX = "rerun bridge run: "
#: Logged before the web viewer's URL (sink serve).
URL_TEXT = "Rerun web viewer:"
#: How often the bridge looks for a plant and a controller, and reports progress, s.
WATCH_PERIOD_S = 0.05

#: Plant states kept while waiting for the controller state of the same stamp.
_PENDING_LIMIT = 1000


def run_label(battery_limit_pu: float) -> str:
    """Label of a run in the views: b=0.3, b=inf."""
    return "b=inf" if math.isinf(battery_limit_pu) else f"b={battery_limit_pu:g}"


class _Run:
    """One run as the bridge sees it: its start stamp, its logger and what was logged."""

    def __init__(self, index: int):
        self.index = index
        self.t0_ns: int | None = None   # stamp of the run's first plant/state
        self.logger: LiveLogger | None = None
        self.label = ""
        self.samples = 0
        self.first_t_s = self.last_t_s = math.nan
        self.reported = 0
        self.plant_gone = False

    def progress(self) -> str:
        return PROGRESS_PREFIX + json.dumps({"run": self.index, "label": self.label, "samples": self.samples,
                                             "first_t_s": self.first_t_s, "last_t_s": self.last_t_s})


class RerunBridge(Node):
    """Pairs plant and controller states by stamp and logs them live, one run after another."""

    def __init__(self, **kwargs):
        super().__init__("rerun_bridge", **kwargs)
        declare(self, parameters())
        values = current_values(self, parameters())
        check_choices(values, parameters())
        sink = (values["sink"], {"save": values["path"], "connect": values["url"]}.get(values["sink"]))
        self._recording, url = open_recording(APP_ID, sink)
        if url:
            self.get_logger().info(f"{URL_TEXT} {url}")
        self._f0_hz = values["f0_hz"]
        self._boundary = None
        self._run: _Run | None = None
        self._runs = 0
        self._labels: dict[str, int] = {}  # label -> runs drawn with it
        self._gate = None                   # pmu subscription while a run may start: what the plant counts
        # stamp -> the half of the sample that arrived first ("plant": speed, "controller": signals)
        self._pending: dict[int, dict] = {}
        subscriptions = {}
        for topic, callback in ((contract.TOPIC_PLANT_STATE, self._on_plant),
                                (contract.TOPIC_CONTROLLER_STATE, self._on_controller),
                                (contract.TOPIC_INVARIANT_SET, self._on_invariant_set)):
            msg_type, name, qos = contract.recorder_endpoint(topic)
            subscriptions[topic] = self.create_subscription(msg_type, name, callback, qos)
        self._plant_sub = subscriptions[contract.TOPIC_PLANT_STATE]
        self._controller_sub = subscriptions[contract.TOPIC_CONTROLLER_STATE]
        self.create_timer(WATCH_PERIOD_S, self._watch)
        self.get_logger().info(f"{READY_TEXT} ({values['sink']})")

    def _watch(self) -> None:
        """Open the gate when a plant and a controller are heard; close it when the plant is gone."""
        plants = self._plant_sub.get_publisher_count()
        if self._gate is None and plants and self._controller_sub.get_publisher_count() and self._run_over():
            self._begin_run()
        elif self._gate is not None and not plants:
            self._end_plant()
        self._report()

    def _run_over(self) -> bool:
        return self._run is None or self._run.plant_gone

    def _begin_run(self) -> None:
        """A new run: the previous one's halves are forgotten, and the gate opens unless it is open."""
        self._runs += 1
        self._run = _Run(self._runs)
        self._pending.clear()
        if self._gate is None:
            msg_type, name, qos = contract.recorder_endpoint(contract.TOPIC_PMU)
            self._gate = self.create_subscription(msg_type, name, lambda msg: None, qos)

    def _end_plant(self) -> None:
        """The run's plant is gone: close the gate (the next plant waits for the bridge again) and flush.

        The run stays current until the next one begins, so that its last controller states,
        still on their way when the plant left, are paired and drawn.
        """
        self.destroy_subscription(self._gate)
        self._gate = None
        self._run.plant_gone = True
        self._flush()

    def _flush(self) -> None:
        if self._run is not None and self._run.logger is not None:
            self._run.logger.flush()
        self._recording.flush()

    def _report(self) -> None:
        run = self._run
        if run is not None and run.samples != run.reported:
            print(run.progress(), flush=True)
            run.reported = run.samples

    def _on_invariant_set(self, msg) -> None:
        self._boundary = np.array([(p.x, p.y) for p in msg.polygon.points])

    def _on_plant(self, msg) -> None:
        stamp_ns, _, speed, _ = contract.plant_state_from_message(msg)
        if self._run_over():  # a plant that did not wait for the bridge: its run starts here
            self._begin_run()
        if self._run.t0_ns is None:
            self._run.t0_ns = stamp_ns
        self._pair(stamp_ns, "plant", speed)

    def _on_controller(self, msg) -> None:
        stamp_ns, signals = contract.controller_state_from_message(msg)
        self._pair(stamp_ns, "controller", signals)

    def _pair(self, stamp_ns: int, half: str, value) -> None:
        """Log the sample once both halves with this stamp are in."""
        sample = self._pending.setdefault(stamp_ns, {})
        sample[half] = value
        if len(sample) < 2 or self._run is None or self._run.t0_ns is None:
            if len(self._pending) > _PENDING_LIMIT:  # a half that never came: forget the oldest
                self._pending.pop(next(iter(self._pending)))
            return
        del self._pending[stamp_ns]
        signals, speed, run = sample["controller"], sample["plant"], self._run
        if run.logger is None:
            b = signals["battery_limit"]
            label = run_label(b)
            self._labels[label] = self._labels.get(label, 0) + 1
            run.label = label if self._labels[label] == 1 else f"{label} #{self._labels[label]}"
            run.logger = LiveLogger(self._recording, run.label, b, self._f0_hz, omega_boundary=self._boundary,
                                    color=colour_rgb(b))
        t_s = (stamp_ns - run.t0_ns) / 1e9  # correctly rounded: 0.98, not 0.9800000000000001
        run.logger.log(t_s, signals["angle_dev"], speed, signals["battery_power"], signals["saturated"] > 0.5,
                       signals["w_hat"])
        run.samples += 1
        run.first_t_s = t_s if run.samples == 1 else run.first_t_s
        run.last_t_s = t_s

    def close(self) -> None:
        """Draw what is pending, report and flush the stream."""
        self._flush()
        self._report()


def main(args=None) -> int:
    """``ros2 run nni_msgs_adapter rerun_bridge``."""
    return run_node(RerunBridge, args, prog="rerun_bridge")


if __name__ == "__main__":
    sys.exit(main())
