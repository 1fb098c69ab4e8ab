"""``nni-replay FILE --pmu-server [HOST:]PORT``: a recording served as IEEE C37.118.2, at its rate, to PDCs.

::

    nni-replay run.mcap --pmu-server [HOST:]PORT [--pmu-idcode N] [--pmu-wait-for-pdcs N]

The stream is a plant's (:class:`nni_plant_sim.pmu_stream.PlantStream`: one
station per generator namespace, named as the plant names it, the same
configuration, header and frame builders) with the recorded ``pmu``
messages in it: the EMF's angle the recorded rotor angle (as the plant's
``pmu`` topic reported it), FREQ from the recorded speed, the ``P_E`` analog
the recorded electrical power, the ``P_ST`` analog the battery power of the
recorded ``plant/state`` at the same stamp; DFREQ is the recorded speed's
rate of change (its central differences) over 2 pi. The EMF's magnitude is
the case's E' (1 pu for the SMIB). A network's terminal voltage and current
are there when the recording gives what the plant computed them from: the
case (``case``), its scenario in the plant's parameters (``network_plant``,
the node's defaults for what it leaves out: :func:`recorded_plant_values`)
applied from t = 0 (``fault_at_start``), and every generator's true angle
(``plant/state``) at the sample (:func:`nni_plant_sim.phasors.terminal_phasors`,
the network plant's own); otherwise (the SMIB, a fault started by a service
call at an instant not recorded, parameters that give no scenario) they are
left out and the header frame says why. A generator without a sample at an
instant the others have is sent as "do not use" (STAT) there, and with
terminal phasors so is every generator (their currents need every angle).

Time: each frame carries its sample's stamp, as the plant's stream did
(lockstep: the simulated clock from the profile's epoch; realtime: the
recorded wall-clock instant), and goes out when as much wall time has passed
since the first as the stamps say (the recorded rate, 10 s of a lockstep run
in 10 s). STAT says the clock is not synchronised, FRACSEC's time quality
"not reliable": these are recorded instants, not a clock's. The trigger bit
marks a disturbance applied at the run's start and its breakpoints.

The stream starts once ``--pmu-wait-for-pdcs`` PDCs have turned data on
(none by default: at once). Progress as ``nni-demo --pmu-server`` prints
it: where the stream listens, one line per PDC that connects, turns data on
or off, or goes away, and at the end the frames offered and, per PDC, sent
and dropped. Bad input (no run parameters, no ``pmu`` samples, a rate or a
nominal frequency C37.118 does not allow, an address that cannot be
listened on) is one line, exit 2.
"""

from __future__ import annotations

import math
import time

import numpy as np

from nni_msgs_adapter.c37118 import cli
from nni_msgs_adapter.c37118.clock_sync import UNKNOWN
from nni_msgs_adapter.recording.network_runs import namespace_order, recorded_case
from nni_battery_controller.replay_load import PROG, load, readable_runs
from nni_msgs_adapter.recording.runs import run_metadata, split_topic
from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.cli_support import CliError
from nni_plant_sim import network_plant_config, plant_config, scenarios
from nni_plant_sim.scenarios import StartingAt
from nni_plant_sim.cases import load_network
from nni_plant_sim.network_scenarios import AngleDisplacement
from nni_plant_sim.phasors import frequency_hz, terminal_phasors
from nni_plant_sim.pmu_stream import SMIB_STATION, PlantStream, network_station_names, station_values

#: Where the run parameters (``nni_run``) hold the plant's: the SMIB demo's and the network demo's.
SMIB_PLANT_KEY, NETWORK_PLANT_KEY = "plant", "network_plant"
#: FREQ/DFREQ as integers: what every PDC reads (the plants' default).
FREQ_FORMAT = "integer"
#: Seconds the stream gets after its last frame to hand every PDC what it queued.
DRAIN_S = 2.0
_POLL_S = 0.05


class _RecordedClock:
    """The clock of recorded instants: known to be in sync with nothing now."""

    @staticmethod
    def state():
        return UNKNOWN


def recorded_samples(recording) -> dict[str, list]:
    """Per namespace, its ``pmu`` samples ``(stamp_ns, delta, speed, P_E)`` in stamp order."""
    samples: dict[str, list] = {}
    for record in recording.messages:
        split = split_topic(record.topic)
        if split is None or split[1] != contract.TOPIC_PMU:
            continue
        try:
            (stamp_ns, delta, speed), efforts, _seal = contract.pmu_from_bytes(record.cdr_bytes)
        except contract.ContractError as error:
            raise CliError(f"{recording.path}: malformed message on {record.topic}: {error}") from None
        samples.setdefault(split[0], []).append((stamp_ns, delta, speed, efforts[0] if efforts else math.nan))
    return {namespace: sorted(rows) for namespace, rows in samples.items()}


class RecordedStream:
    """What the recording streams: station names, rate, nominal frequency, clock, and per instant its values."""

    def __init__(self, recording, parameters: dict):
        path = recording.path
        samples = recorded_samples(recording)
        if not samples:
            raise CliError(f"{path}: no {contract.TOPIC_PMU} messages: nothing to stream")
        self.namespaces = sorted(samples, key=namespace_order)
        case = _case(path, parameters)
        plant = recorded_plant_values(parameters, case)
        self.fault_at_start = bool(plant["fault_at_start"])
        self.net, self.scenario, self.terminal_missing = None, None, "a SMIB has no terminal bus model"
        if case is not None:
            self.net = net = load_network(case)
            if len(self.namespaces) != net.size:
                raise CliError(f"{path}: {case} has {net.size} generators, the recording's pmu samples "
                               f"{len(self.namespaces)} namespace(s)")
            self.names = network_station_names(self.namespaces, net.names)
            self.nominal_hz = net.f0_hz
            self.plant = f"{case}, {net.size} generators"
            self.scenario, self.terminal_missing = _network_in_force(net, plant, self.fault_at_start)
        else:
            self.names = [namespace.strip("/") or SMIB_STATION for namespace in self.namespaces]
            self.nominal_hz = plant["f0_hz"]
            self.plant = "the SMIB generator" if self.namespaces == [""] else f"{len(self.namespaces)} generators"
        self.rate_hz, self.lockstep = plant["pmu_rate_hz"], plant["mode"] == "lockstep"
        if not isinstance(self.rate_hz, (int, float)) or not isinstance(self.nominal_hz, (int, float)):
            raise CliError(f"{path}: the recorded reporting rate ({self.rate_hz!r}) or nominal frequency "
                           f"({self.nominal_hz!r}) is no number")
        self._fill(path, samples, readable_runs(recording))
        self.breakpoints = _breakpoints(plant, case) if self.fault_at_start else ()

    @property
    def terminal(self) -> bool:
        """Whether the stream carries terminal V and I (the recording gives the network in force)."""
        return self.terminal_missing is None

    def _fill(self, path, samples: dict, runs: dict) -> None:
        """Arrays (instants, stations): every instant any generator reported; NaN where one did not."""
        self.stamp_ns = np.unique(np.concatenate([[row[0] for row in samples[ns]] for ns in self.namespaces]))
        if self.stamp_ns.size < 2:
            raise CliError(f"{path}: {self.stamp_ns.size} pmu sample(s): too few to stream at a rate")
        shape = (self.stamp_ns.size, len(self.namespaces))
        delta, speed, self.p_elec_pu, self.battery_pu, self.rocof_hz_per_s, true_delta = (
            np.full(shape, math.nan) for _ in range(6))
        for column, namespace in enumerate(self.namespaces):
            rows = np.array(samples[namespace], dtype=float)
            stamps = np.array([row[0] for row in samples[namespace]], dtype=np.int64)
            at = np.searchsorted(self.stamp_ns, stamps)
            delta[at, column], speed[at, column], self.p_elec_pu[at, column] = rows[:, 1], rows[:, 2], rows[:, 3]
            if stamps.size >= 2:  # over the generator's own samples: one it lacks spoils no neighbour's
                self.rocof_hz_per_s[at, column] = np.gradient(rows[:, 2], (stamps - stamps[0]) * 1e-9) / (2 * math.pi)
            run = runs.get(namespace)
            if run is not None:
                held = np.isin(run.stamp_ns, self.stamp_ns)
                rows_at = np.searchsorted(self.stamp_ns, run.stamp_ns[held])
                self.battery_pu[rows_at, column] = run.battery_power_pu[held]
                true_delta[rows_at, column] = run.delta_rad[held]
        self.frequency_hz = frequency_hz(speed, self.nominal_hz)
        seconds = (self.stamp_ns - self.stamp_ns[0]) * 1e-9
        # Simulated time of each sample: the stamp in lockstep; realtime, the reporting grid's instant since
        # the first sample (t = 0), so that a sample falls on the side of a breakpoint the plant saw it on.
        self.t_s = self.stamp_ns * 1e-9 if self.lockstep else np.round(seconds * self.rate_hz) / self.rate_hz
        emf_pu = np.ones(len(self.namespaces)) if self.net is None else np.asarray(self.net.emf_pu, dtype=float)
        phasors = np.broadcast_to(emf_pu, shape)[:, :, None].astype(complex)
        if self.terminal:
            phasors = np.stack([self._terminal(t_s, row) for t_s, row in zip(self.t_s.tolist(), true_delta)])
        self.magnitude, self.angle_rad = np.abs(phasors), np.angle(phasors)
        self.angle_rad[:, :, 0] = delta  # the EMF's angle: the recorded measurement, as the plant sent it

    def _terminal(self, t_s: float, true_delta: np.ndarray) -> np.ndarray:
        """``(N, 3)``: E', V_t, I_t (pu of the machine's rating) at the recorded true angles, as the plant's."""
        net = self.net
        emf, current, voltage = terminal_phasors(net, self.scenario.network(t_s, net)[1], true_delta)
        return np.column_stack((emf, voltage, current / (net.mbase_mva / net.base_mva)))

    def header(self, source: str) -> str:
        """The first sentence of the header frame: what is replayed and what is left out."""
        terminal = (" Terminal V/I of the recorded true state (plant/state) with the recorded scenario's network."
                    if self.terminal else f" Left out: terminal V/I ({self.terminal_missing}).")
        return (f"nni-replay {source}: a {'lockstep' if self.lockstep else 'realtime'} recording of {self.plant}, "
                f"replayed at its rate.{terminal} DFREQ is the recorded speed's central difference / 2 pi; STAT "
                "and FRACSEC say the clock is not synchronised (recorded instants)")

    def measure(self, k: int):
        """``measure(stat)`` of instant k, for :meth:`PlantStream.offer`."""
        return lambda stat: station_values(stat, self.magnitude[k], self.angle_rad[k], self.frequency_hz[k],
                                           self.rocof_hz_per_s[k],
                                           np.column_stack((self.p_elec_pu[k], self.battery_pu[k])))


def _network_in_force(net, plant: dict, fault_at_start: bool):
    """``(scenario from t = 0, None)`` when the recorded parameters give the network in force at every sample,
    else ``(None, why not)``."""
    if not fault_at_start:
        return None, "the run's disturbance started at a service call, whose instant the recording does not hold"
    try:
        fault = network_plant_config.scenario_from(net, plant)
    except (KeyError, TypeError, ValueError) as error:
        return None, f"the run parameters give no scenario: {error}"
    return StartingAt(fault, 0.0, AngleDisplacement(np.zeros(net.size))), None


def recorded_plant_values(parameters: dict, case: str | None) -> dict:
    """The parameters the run's plant node had: its defaults (the node's YAML), overridden by those recorded
    (``nni-demo`` records what it sets; the rate and mode also at the top level, which win)."""
    specs = network_plant_config.parameters() if case is not None else plant_config.parameters()
    recorded = parameters.get(NETWORK_PLANT_KEY if case is not None else SMIB_PLANT_KEY)
    top = {name: parameters[key] for key, name in (("rate_hz", "pmu_rate_hz"), ("mode", "mode")) if key in parameters}
    return {**{spec.name: spec.default for spec in specs}, **(recorded if isinstance(recorded, dict) else {}), **top}


def _case(path, parameters: dict) -> str | None:
    try:
        return recorded_case(parameters)
    except ValueError as error:
        raise CliError(f"{path}: {error}") from None


def _breakpoints(plant: dict, case: str | None) -> tuple:
    """The recorded scenario's breakpoints (s from the run's start), () if the parameters do not give it."""
    try:
        if case is None:
            return tuple(scenarios.from_values(plant).breakpoints())
        return tuple(network_plant_config.scenario_from(load_network(case), plant).breakpoints())
    except (KeyError, TypeError, ValueError):
        return ()


def serve(args) -> int:
    """Read the recording, check the stream it makes, then serve it (paced) and report."""
    recording = load(args)
    try:
        parameters = run_metadata(recording)
    except ValueError as error:
        raise CliError(str(error)) from None
    if parameters is None:
        raise CliError(f"{args.recording}: holds no run parameters (nni_run): its rate, nominal frequency and "
                       "clock are not known")
    source = RecordedStream(recording, parameters)
    host, port = cli.checked_stream(args, source.rate_hz, source.nominal_hz)
    stream = PlantStream((host, port), args.pmu_idcode, source.names, source.rate_hz, source.nominal_hz,
                         source.terminal, FREQ_FORMAT, source.lockstep, source.header(args.recording), clock=_RecordedClock())
    try:
        stream.start()
    except ValueError as error:
        raise CliError(str(error)) from None
    try:
        wait = f", waiting for {args.pmu_wait_for_pdcs} PDC(s)" if args.pmu_wait_for_pdcs else ""
        print(f"{PROG}: {args.recording}: {source.stamp_ns.size} samples of {len(source.names)} station(s) at "
              f"{source.rate_hz:g} frames/s ({'lockstep' if source.lockstep else 'realtime'}), C37.118 IDCODE "
              f"{args.pmu_idcode}{wait}", flush=True)
        print(f"  C37.118 stream listening on {stream.where}", flush=True)
        while stream.streaming < args.pmu_wait_for_pdcs:
            _print_events(stream)
            time.sleep(_POLL_S)
        _play(stream, source)
        _drain(stream)
    finally:
        stream.stop()
        _print_events(stream)
    print(cli.summary_line(stream.summary()), flush=True)
    return 0


def _play(stream, source: RecordedStream) -> None:
    """Offer every instant when its stamp, counted from the first, is due in wall time."""
    if source.fault_at_start:
        stream.disturbed()
    start, first = time.monotonic(), int(source.stamp_ns[0])
    for k, stamp_ns in enumerate(source.stamp_ns.tolist()):
        delay = start + (stamp_ns - first) * 1e-9 - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        stream.offer(stamp_ns, float(source.t_s[k]), source.breakpoints, source.measure(k))
        _print_events(stream)


def _drain(stream) -> None:
    """Wait (at most :data:`DRAIN_S`) until no PDC has frames queued."""
    deadline = time.monotonic() + DRAIN_S
    while time.monotonic() < deadline and any(pdc["queued"] for pdc in stream.server.counters()["pdcs"]):
        time.sleep(_POLL_S)


def _print_events(stream) -> None:
    for line in stream.events():
        print(f"  {line}", flush=True)
