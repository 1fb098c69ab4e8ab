"""Controller node: the sampled-data saturated NNI law (H3-hat) on PMU measurements.

Only translates between ROS and :class:`~nni_battery_controller.controller_core.ControllerCore`
(the input gate, the centre of inertia for reference coi, the law the offline sampled simulation runs).
Its measurements come from ``pmu`` or, with ``measurement_topic c37118/pmu``, from the plant's C37.118
stream through the PDC client node.
With ``authentication hmac`` (the default) it needs the run's key
(``NNI_COMMAND_KEY_FILE``; without one it stops with one line): it acts only on
measurements sealed by the plant under their topic's key, fresh and in
sequence (:func:`nni_msgs_adapter.ros.command_auth.MeasurementVerifier`), takes
the plant's end of run only when sealed, takes no time from ``/clock`` (a
rosgraph_msgs/Clock cannot carry a seal: in lockstep the sealed stamp is the
plant's clock, in realtime the wall clock is), and seals every command and
state it sends. Everything else is dropped and counted
(:data:`.controller_core.TRUST_COUNTERS`, ERROR on diagnostics). With
``authentication none`` nothing is sealed or checked, for a plant started with
``command_authentication none``.
"""

from __future__ import annotations

import sys

from nni_battery_controller.controller_config import ControllerConfig, parameters, prepared
from nni_battery_controller.controller_core import ControllerCore
from nni_msgs_adapter.ros import command_auth, contract
from nni_msgs_adapter.ros.loop_node import LoopNode, PolledReader, StampedPublisher
from nni_msgs_adapter.ros.node_main import run_node


class ControllerNode(LoopNode):
    """Answers every PMU measurement that passes the gate with a battery power command."""

    def __init__(self, plant: PlantReaders | None = None, **kwargs):
        """``plant``: the process's readers of the plant's /clock and /diagnostics when several controllers
        share them (composed), else the node's own."""
        super().__init__("controller", parameters(), **kwargs)
        config = ControllerConfig(self.initial_values, self.get_namespace())
        self._core = ControllerCore(config)
        key = run_key(config.authenticated)
        self._commands = StampedPublisher(self, contract.TOPIC_BATTERY_COMMAND, key=key)
        self._states = StampedPublisher(self, contract.TOPIC_CONTROLLER_STATE, key=key)
        ControllerCore.warm_up(config)
        self._pmu_subs = [contract.subscribe(self, config.measurement_topic, lambda data, i=i: self._on_pmu(i, data),
                                             ns, raw=True) for i, ns in enumerate(config.pmu_namespaces)]
        #: With the key: per pmu topic its seals' verifier, and the plant's end-of-run notices'.
        self._verifiers = None if key is None else [command_auth.MeasurementVerifier(key, sub.topic_name)
                                                    for sub in self._pmu_subs]
        self._status_verifier = None if key is None else command_auth.Verifier(
            key, contract.status_topic(f"{self.get_namespace().rstrip('/')}/plant"), "status")
        self._lockstep = False  # the last sealed measurement of the own plant said lockstep
        self._own_plant_readers = plant is None
        self._plant = PlantReaders(self) if plant is None else plant
        self._plant.listen(self._on_diagnostics)
        # The silence watchdog, re-armed only when it fires, for the instant the silence since the last accepted
        # measurement would reach stale_after_s. A timer at the sample rate doubled the wake-ups (profiled); one
        # restarted by each measurement woke the EventsExecutor's timer thread on every sample (ieee39 lockstep,
        # separate: 0.4-3.6 ms of the ten controllers' CPU a sample over two alternating A/B runs).
        self._stale_timer = self.create_timer(config.stale_after_s, self._check_stale)

    def _validate(self, values: dict) -> ControllerConfig:
        return prepared(self._core.config.values, values, self.get_namespace(), self._core.active)

    def _install(self, config: ControllerConfig) -> None:
        self._core.reconfigure(config)
        self._arm_stale_check(self.now_ns())

    def _on_pmu(self, index: int, data: bytes) -> None:
        arrival_ns = self.now_ns()
        try:
            reading, effort, seal = contract.pmu_from_bytes(data)
        except contract.ContractError:
            reading, effort, seal = None, (), None
        if self._verifiers is None:
            answer = self._core.receive(index, reading, effort, self._pmu_subs[index].handle.get_publisher_count(),
                                        arrival_ns, self._plant.newest_clock_ns(), self._plant.clock_writers)
        else:
            answer = self._sealed(index, reading, effort, seal, arrival_ns)
        if answer is not None:
            self._commands.publish(answer.stamp_ns, answer.power_pu)
            if self._states.read():  # W_hat and the state's bytes only for a recorder or a viewer
                self._states.publish(*answer.signals())

    def _sealed(self, index: int, reading, effort, seal, arrival_ns: int):
        """A measurement under authentication hmac: to the core only if its seal verifies, fresh and in sequence.

        Its writer is then the plant, whatever else writes on the topic (the core is told one writer). Its stamp
        is checked against itself in lockstep (a sealed lockstep stamp is the plant's simulated clock) and against
        the wall clock in realtime.
        """
        verifier = self._verifiers[index]
        verdict = command_auth.UNAUTHENTICATED if reading is None else verifier.check(seal, *reading, *effort)
        if verdict != command_auth.AUTHENTIC:
            self._refuse("replayed_measurements" if verdict == command_auth.REPLAYED
                         else "unauthenticated_measurements", self._pmu_subs[index].topic_name)
            return None
        lockstep = verifier.flag == command_auth.LOCKSTEP_FLAG
        if index == (0 if self._core.coi is None else self._core.coi.own):
            self._lockstep = lockstep
        writers = self._plant.clock_writers()
        if writers > (1 if lockstep else 0) and writers > self._core.trust["foreign_clock_writers"]:
            self._core.trust["foreign_clock_writers"] = writers - (1 if lockstep else 0)
            self._alarm(f"{writers} writer(s) on /clock in a {'lockstep' if lockstep else 'realtime'} run: "
                        "its ticks are not used")
        return self._core.receive(index, reading, effort, 1, arrival_ns, reading[0] if lockstep else None,
                                  _no_writers)

    def _refuse(self, counter: str, where: str) -> None:
        """An input that is not the plant's: counted, and the first of each kind named at ERROR at once."""
        self._core.trust[counter] += 1
        if self._core.trust[counter] == 1:
            self._alarm(f"{counter.replace('_', ' ')} on {where}: dropped (not sealed by this run's plant); "
                        "the run is compromised")

    def _alarm(self, text: str) -> None:
        self.get_logger().error(text)
        self.publish_diagnostics()

    def _on_diagnostics(self, data: bytes) -> None:
        ended, verdict = contract.plant_run_ended(data, self.get_namespace(), self._status_verifier)
        if verdict is not None and verdict != command_auth.AUTHENTIC:
            self._refuse("unauthenticated_statuses", contract.TOPIC_DIAGNOSTICS)
        if ended and self._core.end_of_run():
            self.get_logger().info(f"the plant's run ended after {self._core.gate.counts['samples']} answered "
                                   "measurements: waiting for the next run")

    def _check_stale(self) -> None:
        now_ns = self.now_ns()
        if self._verifiers is None:
            lockstep = self._plant.clock_writers() > 0
        else:  # the sealed stream said lockstep, and its plant is still there
            lockstep = self._lockstep and self._pmu_subs[0].handle.get_publisher_count() > 0
        stamp_ns = self._core.silence(now_ns, lockstep)
        if stamp_ns is not None:
            self._commands.publish(stamp_ns, 0.0)
            self.get_logger().warning(f"no measurement for {self._core.config.stale_after_s:g} s: battery power set to zero")
        self._arm_stale_check(now_ns)

    def _arm_stale_check(self, now_ns: int) -> None:
        """The watchdog's next fire: when the silence would become stale, else (none to watch) stale_after_s on."""
        self._stale_timer.timer_period_ns = self._core.gate.silence_check_in_ns(now_ns)
        self._stale_timer.reset()

    def publish_diagnostics(self) -> None:
        self.publish_status("controller", *self._core.status())

    def close(self) -> None:
        super().close()
        if self._own_plant_readers:
            self._plant.destroy()


class PlantReaders:
    """What a controller hears from the plant beside its measurements: ``/clock`` and ``/diagnostics``.

    ``/clock`` (lockstep) is read when a measurement comes, by a reader no executor dispatches
    (:class:`.PolledReader`: the newest /clock heard then); ``/diagnostics`` by a subscription whose
    callback hands every message to each controller listening (:meth:`listen`: the plant's end-of-run
    notice). Both topics are absolute: every controller of a composed process hears the same
    messages, so they share one PlantReaders (``ControllerNode(plant=...)``), and the process gets
    each /clock sample and each status array once instead of once per controller. With 52
    controllers in one process, their own readers took every lockstep sample's /clock 52 times (52
    histories, 52 acknowledgements to the plant), and every second's 53 status arrays (52
    controllers' and the plant's) 2756 times through the executor. :meth:`destroy` it before its node.
    """

    def __init__(self, node):
        self._clock = PolledReader(node, contract.TOPIC_CLOCK)
        self.clock_writers = self._clock.get_publisher_count
        self._clock_ns: int | None = None
        self._listeners = []
        contract.subscribe(node, contract.TOPIC_DIAGNOSTICS, self._on_diagnostics, raw=True)

    def newest_clock_ns(self) -> int | None:
        """The time of the newest /clock heard (ns), None before any."""
        data = self._clock.latest()
        if data is not None:
            try:
                self._clock_ns = contract.clock_from_bytes(data)
            except contract.ContractError:
                pass  # no time in it: the stamps stay checked against the last one heard
        return self._clock_ns

    def listen(self, callback) -> None:
        """``callback(data)`` gets the bytes of every ``/diagnostics`` message from now on."""
        self._listeners.append(callback)

    def _on_diagnostics(self, data: bytes) -> None:
        for callback in self._listeners:
            callback(data)

    def destroy(self) -> None:
        self._clock.destroy()


def _no_writers() -> int:
    """No /clock writer counts: an authenticating controller takes no time from /clock."""
    return 0


def run_key(authenticated: bool) -> bytes | None:
    """The run's key for authentication hmac (None for none); ValueError (one line) without one."""
    if not authenticated:
        return None
    key = command_auth.key_from_environment()
    if key is None:
        raise ValueError(f"authentication hmac needs the run's key: set {command_auth.KEY_FILE_ENV} to the file of "
                         f"{command_auth.KEY_BYTES} random bytes the plant has (mode 0600), or start the controller "
                         "with -p authentication:=none (only beside a plant with command_authentication none)")
    return key


def main(args=None) -> int:
    """``ros2 run nni_battery_controller controller_node``."""
    return run_node(ControllerNode, args, prog="controller_node")


if __name__ == "__main__":
    sys.exit(main())
