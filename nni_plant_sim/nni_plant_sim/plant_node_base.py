"""What every plant node does in ROS: N generators, each with a CommandChannel and a PMU, behind one reporting loop.

The SMIB plant (:mod:`.plant_node`) is N = 1 in the node's own namespace
(relative topics ``pmu``, ``plant/state``, ``battery/command``); the network
plant (:mod:`.network_plant_node`) has generator i under ``/gen<i>``. This
class translates between ROS and the cores for both: its parameters
(:func:`.plant_config.run_parameters` and the node's own) are declared,
validated and applied as every loop node's
(:class:`nni_msgs_adapter.ros.loop_node.LoopNode`); it waits for the
subscribers (:class:`.reporting.SubscriberWait`), runs the reporting loop
(:class:`.reporting.LockstepStepper` or :class:`.reporting.RealtimeReporter`),
publishes what it returns (per generator its measurement, in lockstep then
``/clock``, then the true states), hands each battery command and the writers
on each command topic to the generator's :class:`.reporting.CommandChannel`,
serves ``plant/start_fault`` (the fault starts then; ``fault_at_start``: at
t = 0) and publishes one status per generator on ``/diagnostics`` (``run_ended`` in
the callback of the run's last sample; at exit also printed as one JSON line).
With ``pmu_port`` it also serves every sample as IEEE C37.118.2
(:mod:`.pmu_stream`: listening from the node's start, each PDC's connection
and departure logged, the stream's counters as status ``c37118_server`` on
``/diagnostics``; the run waits for ``pmu_wait_for_pdcs`` PDCs with data on;
at exit its totals and each PDC's frames sent and dropped as one JSON line,
``SUMMARY_PREFIX_STREAM``, before the plant's own).

Commands (``command_authentication``): ``hmac`` (the default) admits only
those whose seal verifies under the run's key (``NNI_COMMAND_KEY_FILE``,
:mod:`nni_msgs_adapter.ros.command_auth`; one key per generator's command
topic); ``none`` pairs with the one writer on the topic, as before keys.
``battery_energy_pu_s`` (finite): every generator's battery has that much
energy (:mod:`.battery`, in the reporting core's delay line): an empty one
gives nothing, ``plant/state`` carries the power it gives, and its status the
charge and when it ran empty or full. ``hold_until_released``: the run does not start before the process gets
SIGUSR1 (the demo or the launch file sends it once every node's parameters,
read back from the lines they print at start, are what it passed).

A plant node sets, in :meth:`_configure_plant`: ``namespaces`` (``("",)``:
the node's own), ``_plant`` (what :func:`.integrators.advance` integrates),
``_fault`` and ``_before`` (the scenario and the pre-fault one, see
:class:`.scenarios.StartingAt`) and ``_labels`` (extra status values per
generator); and it gives :meth:`_integrate`, :meth:`_state_of`,
:meth:`_frames`, and for the C37.118 stream :meth:`_stream_description` and
:meth:`_synchrophasors`.
"""

from __future__ import annotations

import json
import math
import signal

from rclpy.task import Future
from std_srvs.srv import Trigger

from nni_msgs_adapter.ros import command_auth, contract
from nni_msgs_adapter.ros.loop_node import LoopNode, StampedPublisher
from nni_msgs_adapter.ros.ros_params import locked_changes
from nni_plant_sim.battery import EnergyStore
from nni_plant_sim.plant_config import link_from
from nni_plant_sim.pmu_stream import STREAM_PARAMETERS, SUMMARY_PREFIX_STREAM, PlantStream
from nni_plant_sim.reporting import CommandChannel, LockstepStepper, PmuSensor, RealtimeReporter, SubscriberWait
from nni_plant_sim.scenarios import StartingAt


class PlantNodeBase(LoopNode):
    """A plant of generators reporting like PMUs; ``summary_prefix`` starts its JSON line at exit."""

    summary_prefix = ""

    def __init__(self, node_name: str, specs, **kwargs):
        super().__init__(node_name, specs, **kwargs)
        values = self.initial_values
        self._loop = None  # the reporting core, from the start of the run
        self._key = run_key(values["command_authentication"])
        self._released = not values["hold_until_released"]
        if not self._released:
            signal.signal(signal.SIGUSR1, lambda number, frame: setattr(self, "_released", True))
        self._configure(values)
        self._stream, self._pdc_wait = self._open_stream(values)
        self._lockstep, self.done = values["mode"] == "lockstep", Future()
        self._scenario = StartingAt(self._fault, math.inf, self._before)  # pre-fault until the fault starts
        self._wait = SubscriberWait(values["wait_for_subscribers"], values["discovery_settle_s"],
                                    values["wait_timeout_s"], self.now_ns())
        self._t0_ns, self._finished_ns, self._gave_up = None, None, False
        self._status_signers = None  # made at the first status (the node's name is resolved by then)
        self._writer_counts = [-1] * len(self.namespaces)
        # With the run's key every measurement and true state is sealed (measurements with the mode: the
        # controller takes a lockstep stamp as the plant's clock), each topic under its own key.
        mode = command_auth.LOCKSTEP_FLAG if self._lockstep else command_auth.REALTIME_FLAG
        self._pmu_pubs = [StampedPublisher(self, contract.TOPIC_PMU, ns, key=self._key, flag=mode)
                          for ns in self.namespaces]
        self._state_pubs = [StampedPublisher(self, contract.TOPIC_PLANT_STATE, ns, key=self._key)
                            for ns in self.namespaces]
        self._clock_pub = StampedPublisher(self, contract.TOPIC_CLOCK) if self._lockstep else None
        self._command_subs = [contract.subscribe(self, contract.TOPIC_BATTERY_COMMAND,
                                                 lambda data, i=i: self._on_command(i, data), ns, raw=True)
                              for i, ns in enumerate(self.namespaces)]
        self.create_service(Trigger, contract.SERVICE_START_FAULT, self._on_start_fault)
        # Warm the sample path once, publishing nothing. Profiled: the first pass costs ~5 ms (numpy's
        # first calls), which sample 0 would otherwise pay as latency.
        self._integrate(0.0, 1.0 / values["pmu_rate_hz"], self._state_of(self._fault), (0.0,) * len(self.namespaces))
        self._start_timer = self.create_timer(0.01, self._try_start)
        self._run_timers = [self.diagnostics_timer]

    # --- parameters ----------------------------------------------------------------------

    def _configure(self, values: dict) -> None:
        self._values = values
        self._configure_plant(values)
        topics = [self.resolve_topic_name(contract.endpoint(contract.TOPIC_BATTERY_COMMAND, ns)[1])
                  for ns in self.namespaces]
        self._channels = [CommandChannel(rating, round(values["command_timeout_s"] * 1e9),
                                         None if self._key is None else command_auth.CommandVerifier(self._key, topic))
                          for rating, topic in zip(self._ratings(values), topics)]
        self._sensors = [PmuSensor(values["noise_angle_std_rad"], values["noise_speed_std_rad_s"],
                                   values["quantisation_rad"], values["noise_seed"] + i) for i in range(len(self.namespaces))]
        self._exact_sensors = all(sensor.exact for sensor in self._sensors)

    def _ratings(self, values: dict) -> list[float]:
        """The battery rating of each generator, pu of its machine's rating."""
        return [values["battery_rating_pu"]] * len(self.namespaces)

    def _validate(self, values: dict) -> dict:
        if self._loop is not None:
            locked_changes(self._values, values, [spec.name for spec in self.specs])
        locked_changes(self._values, values, *self._locked_at_start())
        locked_changes(self._values, values, (*STREAM_PARAMETERS, *(("pmu_rate_hz", "f0_hz") if self._stream else ())),
                       "once the node is up (its C37.118 stream is configured)")
        self._check(values)
        link_from(values)
        return values

    def _install(self, values: dict) -> None:
        if values != self._values:  # a change before the run (during it every parameter is locked)
            self._configure(values)

    def _open_stream(self, values: dict):
        """The C37.118 stream ``pmu_port`` asks for, listening, and its wait for PDCs; (None, None) without."""
        stream = PlantStream.from_values(values, *self._stream_description())
        if stream is None:
            return None, None
        self.get_logger().info(stream.start())
        self.create_timer(0.2, self._log_stream_events)
        return stream, SubscriberWait(values["pmu_wait_for_pdcs"], 0.0, values["wait_timeout_s"], self.now_ns())

    def _log_stream_events(self) -> None:
        """A PDC connected, went away, turned data on or off: one line each."""
        for line in self._stream.events():
            self.get_logger().info(line)

    # --- start ---------------------------------------------------------------------------

    def _try_start(self) -> None:
        pmu_pubs = [pub.publisher for pub in self._pmu_pubs]
        readers = [pub.get_subscription_count() for pub in pmu_pubs]
        writers = [sub.get_publisher_count() for sub in self._command_subs]
        fewest, silent = readers.index(min(readers)), writers.index(min(writers))
        recorders = [pub.publisher.get_subscription_count() for pub in self._state_pubs]
        unseen = recorders.index(min(recorders))
        wanted = self._values["wait_for_recorders"]
        also = [f"{wanted} recorder(s) on {self._state_pubs[unseen].publisher.topic_name} (has {recorders[unseen]})"] \
            if recorders[unseen] < wanted else []
        state, level, text = self._wait.poll(self.now_ns(), readers[fewest], writers[silent],
                                             pmu_pubs[fewest].topic_name, self._command_subs[silent].topic_name,
                                             self._released, also)
        if state == "start" and self._pdc_wait is not None:
            state, level, text = self._pdc_wait.poll(self.now_ns(), self._stream.streaming, 1,
                                                     f"the C37.118 stream at {self._stream.where} with data on", "")
        if text is not None:
            contract.log_at(self.get_logger(), level, text)
        self._gave_up = state == "give_up"
        if state != "start":
            return self.done.set_result(True) if self._gave_up else None
        self._start_timer.cancel()
        values = self._values
        # Logged before sample 0: rclpy's first log call is slow (caller lookup); after it, sample 0 took 17-19 ms.
        self.get_logger().info(f"started in {values['mode']} mode at {values['pmu_rate_hz']:g} frames/s"
                               + (f", {len(self.namespaces)} generators" if self.namespaces != ("",) else ""))
        self._check_writers()
        timer = self.create_timer(min(0.05, values["lockstep_timeout_s"] / 4) if self._lockstep
                                  else 1.0 / values["pmu_rate_hz"], self._on_timer)
        self._run_timers.append(timer)
        # Realtime, the reporting grid is the timer's own, its period in whole ns and its phase, so that a
        # tick never comes before its instant and the two never drift apart (60 frames/s: 16,666,666 ns).
        self._t0_ns = self.now_ns() + (0 if self._lockstep else timer.time_until_next_call() - timer.timer_period_ns)
        state = self._state_of(self._before)
        link, energy = link_from(values), values["battery_energy_pu_s"]
        store = None if math.isinf(energy) else EnergyStore([energy] * len(self.namespaces))
        self._loop = (LockstepStepper(self._integrate, state, self._channels, values["duration_s"],
                                      1.0 / values["pmu_rate_hz"], values["lockstep_timeout_s"], link, store)
                      if self._lockstep
                      else RealtimeReporter(self._integrate, state, self._channels, values["duration_s"],
                                            self._t0_ns, timer.timer_period_ns, values["command_timeout_s"], link, store))
        if values["fault_at_start"]:
            self._start_fault_now()
        self._publish(self._loop.start(self.now_ns()))

    def _start_fault_now(self) -> None:
        self._scenario = StartingAt(self._fault, self._loop.t_s, self._before)
        if self._stream is not None:
            self._stream.disturbed()
        self._loop.replace_state(self._state_of(self._fault))

    def _on_start_fault(self, request, response):
        response.success = self._loop is not None and self._scenario.start_s == math.inf
        if response.success:
            self._publish(self._loop.interrupt(self.now_ns()))
            self._start_fault_now()
        response.message = (f"fault started at t = {self._loop.t_s:.6f} s" if response.success else
                            "the run has not started (waiting for subscribers)" if self._loop is None else
                            "the fault has already started")
        return response

    # --- publishing ----------------------------------------------------------------------

    def _publish(self, output) -> None:
        """What the core says to publish: the measurements (lockstep: then /clock) first, then true states."""
        if output is None:
            return
        sample = output.measurement
        if sample is not None:
            frames = self._frames(sample)
            for pub, frame in zip(self._pmu_pubs, frames):
                pub.publish(sample.stamp_ns, *frame)
            if self._stream is not None:
                self._stream.offer(sample.stamp_ns, sample.t_s, self._scenario.breakpoints(),
                                   lambda stat: self._synchrophasors(sample, frames, stat))
            if self._lockstep:  # /clock after the measurement: the controller answers before it reads the clock
                self._loop.sent(self.now_ns())
                self._clock_pub.publish(sample.stamp_ns)
        for report in output.states:
            deltas, speeds = report.state.reshape(2, -1).tolist()
            for pub, delta, speed, power in zip(self._state_pubs, deltas, speeds, report.powers):
                pub.publish(report.stamp_ns, delta, speed, power)
        if output.done:
            for timer in self._run_timers:
                timer.cancel()
            self._finished_ns = self.now_ns()
            self.publish_diagnostics()
            self.done.set_result(True)

    # --- timers and commands -------------------------------------------------------------

    def _on_timer(self) -> None:
        """Realtime: the reporting tick; lockstep: the watchdog of the handshake (zero for the silent at the timeout)."""
        self._check_writers()
        self._publish(self._loop.on_timer(self.now_ns()))

    def _check_writers(self, only: int | None = None) -> None:
        """Tell each channel (or channel ``only``) who writes on its battery/command when that changed.

        A command checks its own channel only, since its verdict depends on that channel's writers alone
        (profiled at N = 10: checking all N on every command cost N x N graph queries a period); the
        timer checks them all. Alarms go out at once.
        """
        for i in range(len(self._channels)) if only is None else (only,):
            sub, channel = self._command_subs[i], self._channels[i]
            count = sub.handle.get_publisher_count()  # rclpy's C call: its wrapper doubled the cost (1.4 us), per command
            if count == self._writer_counts[i] and channel.paired is not None:
                continue
            writers, unlisted = contract.writers_on(self, sub.topic_name, count)
            self._writer_counts[i] = -1 if unlisted or contract.UNNAMED_WRITER in writers.values() else count
            channel.writers(writers, unlisted)
            self._report_events(i)

    def _report_events(self, index: int) -> None:
        """Channel ``index``'s pairings on the log; its alarms on the log at ERROR and in diagnostics at once."""
        ns = self.namespaces[index]
        for alarm, text in self._channels[index].take_events():
            contract.log_at(self.get_logger(), "error" if alarm else "info", f"/{ns}: {text}" if ns else text)
            if alarm:
                self.publish_diagnostics()

    def _on_command(self, index: int, data: bytes) -> None:
        arrival_ns = self.now_ns()
        self._check_writers(index)
        try:
            stamp_ns, power, seal = contract.command_from_bytes(data)
        except contract.ContractError:
            stamp_ns, power, seal = 0, math.nan, None  # malformed: invalid (unauthenticated), as a non-finite power
        if self._loop is None:  # before the run: it answers no measurement; counted by what it is, never applied
            self._channels[index].admit(stamp_ns, power, arrival_ns, seal=seal)
            self._report_events(index)
            return
        # An answer to the stream's stamp (to the microsecond) answers the plant's sample; the seal covers the first.
        sample_ns = stamp_ns if self._stream is None else self._stream.plant_stamp(stamp_ns)
        self._publish(self._loop.command(index, sample_ns, power, arrival_ns, seal, stamp_ns)[1])
        self._report_events(index)

    # --- diagnostics ---------------------------------------------------------------------

    def _generator_values(self) -> list[dict]:
        """Per generator: the run's simulated and wall time and samples, its channel's counters, the power in force."""
        run = {"mode": self._values["mode"], "sim_time_s": 0.0, "samples": 0, "run_wall_s": 0.0}
        if self._loop is not None:
            run.update(sim_time_s=self._loop.t_s, samples=self._loop.sample,
                       run_wall_s=((self._finished_ns or self.now_ns()) - self._t0_ns) * 1e-9)
        return [{**run, **label, "battery_power_pu": channel.power_pu, **channel.summary(),
                 **(self._loop.link_summary(i) if self._loop is not None else {}), **self._charge_summary(i),
                 contract.RUN_ENDED: self._finished_ns is not None}
                for i, (label, channel) in enumerate(zip(self._labels, self._channels))]

    def _charge_summary(self, index: int) -> dict:
        """Generator ``index``'s battery of finite energy: its charge, pu s from empty, the power it gives now (an
        empty one gives none of what is in force), and when it ran empty or full (simulated s; absent until it
        does); nothing for an unlimited one."""
        store = None if self._loop is None else self._loop.store
        if store is None:
            return {}
        values = {"battery_charge_pu_s": store.charge_pu_s[index],
                  "battery_given_pu": self._loop.line.applied_powers()[index]}
        for key, at in (("battery_empty_at_s", store.empty_at_s[index]), ("battery_full_at_s", store.full_at_s[index])):
            if at is not None:
                values[key] = at
        return values

    def publish_diagnostics(self) -> list[dict]:
        """One status per generator (``plant``, namespaced by its hardware_id), all in one message; their values."""
        generators = self._generator_values()
        stamp_ns = self.now_ns()
        statuses = [("plant", *channel.health(self._loop is not None, self._wait.text),
                     self._sealed_status(i, stamp_ns, values), f"/{ns}/plant" if ns else "")
                    for i, (ns, channel, values) in enumerate(zip(self.namespaces, self._channels, generators))]
        if self._stream is not None:
            statuses.append(("c37118_server", *self._stream.status(), ""))
        self.publish_statuses(statuses, stamp_ns)
        return generators

    def _sealed_status(self, index: int, stamp_ns: int, values: dict) -> dict:
        """A generator's status values, with the run's key also ``seal``: its ``run_ended`` sealed for its controller
        (:func:`nni_msgs_adapter.ros.contract.status_topic`, :func:`~nni_msgs_adapter.ros.contract.plant_run_ended`)."""
        if self._key is None:
            return values
        if self._status_signers is None:
            self._status_signers = [command_auth.Signer(self._key, contract.status_topic(
                self.get_fully_qualified_name() if ns == "" else f"/{ns}/plant"), "status") for ns in self.namespaces]
        ended = 1.0 if values[contract.RUN_ENDED] else 0.0
        return {**values, contract.STATUS_SEAL: self._status_signers[index].seal(stamp_ns, ended).decode()}

    def close(self) -> None:
        """Final diagnostics before the node goes (SIGINT/SIGTERM or end of run), also printed as one JSON line.

        The line holds the one generator's values in the node's own namespace, else ``{namespace: values}``.
        """
        if self._loop is not None and self._finished_ns is None:
            self._finished_ns = self.now_ns()  # stopped: the run ends here, and its status says so
        generators = self.publish_diagnostics()
        if self._stream is not None:  # stopped first: its summary holds every PDC's last frame and departure
            self._stream.stop()
            self._log_stream_events()
            print(SUMMARY_PREFIX_STREAM + json.dumps(self._stream.summary()), flush=True)
        print(self.summary_prefix + json.dumps(generators[0] if self.namespaces == ("",) else
                                               dict(zip(self.namespaces, generators))), flush=True)
        if self._gave_up:
            raise SystemExit(1)  # nobody to run with (node_main returns 0 after a node's normal end)


def run_key(authentication: str) -> bytes | None:
    """The run's command key for ``command_authentication`` (None for ``none``); ValueError (one line) without one."""
    if authentication != "hmac":
        return None
    key = command_auth.key_from_environment()
    if key is None:
        raise ValueError(f"command_authentication hmac needs the run's key: set {command_auth.KEY_FILE_ENV} to a file "
                         f"of {command_auth.KEY_BYTES} random bytes of your own (mode 0600), or start the plant with "
                         "-p command_authentication:=none (the one writer on battery/command is trusted)")
    return key
