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
the case's E' (1 pu for the SMIB). Terminal voltage and current are left
out: a recording holds the rotor angles, not the network in force at each
sample (a fault's, a trip's), and the header frame says so. A generator
without a sample at an instant the others have is sent as "do not use"
(STAT) there.

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
from nni_msgs_adapter.recording.replay_load import PROG, load, readable_runs
from nni_msgs_adapter.recording.runs import run_metadata, split_topic
from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.cli_support import CliError
from nni_plant_sim import scenarios
from nni_plant_sim.cases import load_network
from nni_plant_sim.network_plant_config import scenario_from
from nni_plant_sim.phasors import frequency_hz
from nni_plant_sim.pmu_stream import SMIB_STATION, PlantStream, network_station_names, station_values

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
            (stamp_ns, delta, speed), efforts = contract.pmu_from_bytes(record.cdr_bytes)
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
        plant = parameters.get("plant") if isinstance(parameters.get("plant"), dict) else {}
        case = _case(path, parameters)
        if case is not None:
            net = load_network(case)
            if len(self.namespaces) != net.size:
                raise CliError(f"{path}: {case} has {net.size} generators, the recording's pmu samples "
                               f"{len(self.namespaces)} namespace(s)")
            self.names = network_station_names(self.namespaces, net.names)
            self.nominal_hz, emf_pu = net.f0_hz, np.asarray(net.emf_pu, dtype=float)
            self.plant = f"{case}, {net.size} generators"
        else:
            self.names = [namespace.strip("/") or SMIB_STATION for namespace in self.namespaces]
            self.nominal_hz, emf_pu = plant.get("f0_hz"), np.ones(len(self.namespaces))
            self.plant = "the SMIB generator" if self.namespaces == [""] else f"{len(self.namespaces)} generators"
            if not isinstance(self.nominal_hz, (int, float)):
                raise CliError(f"{path}: the run parameters give no nominal frequency (plant.f0_hz)")
        self.rate_hz = parameters.get("rate_hz", plant.get("pmu_rate_hz"))
        if not isinstance(self.rate_hz, (int, float)):
            raise CliError(f"{path}: the run parameters give no reporting rate (rate_hz)")
        self.lockstep = parameters.get("mode", plant.get("mode")) == "lockstep"
        self._fill(path, samples, readable_runs(recording), emf_pu)
        self.fault_at_start = bool(plant.get("fault_at_start", False))
        self.breakpoints = _breakpoints(plant, case) if self.fault_at_start else ()

    def _fill(self, path, samples: dict, runs: dict, emf_pu: np.ndarray) -> None:
        """Arrays (instants, stations): every instant any generator reported; NaN where one did not."""
        self.stamp_ns = np.unique(np.concatenate([[row[0] for row in samples[ns]] for ns in self.namespaces]))
        if self.stamp_ns.size < 2:
            raise CliError(f"{path}: {self.stamp_ns.size} pmu sample(s): too few to stream at a rate")
        shape = (self.stamp_ns.size, len(self.namespaces))
        self.delta_rad, speed, self.p_elec_pu, self.battery_pu, self.rocof_hz_per_s = (
            np.full(shape, math.nan) for _ in range(5))
        for column, namespace in enumerate(self.namespaces):
            rows = np.array(samples[namespace], dtype=float)
            stamps = np.array([row[0] for row in samples[namespace]], dtype=np.int64)
            at = np.searchsorted(self.stamp_ns, stamps)
            self.delta_rad[at, column], speed[at, column], self.p_elec_pu[at, column] = rows[:, 1], rows[:, 2], rows[:, 3]
            if stamps.size >= 2:  # over the generator's own samples: one it lacks spoils no neighbour's
                self.rocof_hz_per_s[at, column] = np.gradient(rows[:, 2], (stamps - stamps[0]) * 1e-9) / (2 * math.pi)
            run = runs.get(namespace)
            if run is not None:
                battery = dict(zip(run.stamp_ns.tolist(), run.battery_power_pu.tolist()))
                self.battery_pu[:, column] = [battery.get(stamp, math.nan) for stamp in self.stamp_ns.tolist()]
        self.frequency_hz = frequency_hz(speed, self.nominal_hz)
        seconds = (self.stamp_ns - self.stamp_ns[0]) * 1e-9
        self.magnitude = np.broadcast_to(emf_pu, shape)
        # Simulated time of each sample: the stamp in lockstep, the time since the first (t = 0) in realtime.
        self.t_s = self.stamp_ns * 1e-9 if self.lockstep else seconds

    def header(self, source: str) -> str:
        """The first sentence of the header frame: what is replayed and what is left out."""
        return (f"nni-replay {source}: a {'lockstep' if self.lockstep else 'realtime'} recording of {self.plant}, "
                "replayed at its rate. Left out: terminal V/I (a recording holds the rotor angles, not the network "
                "in force at each sample); DFREQ is the recorded speed's central difference / 2 pi; STAT and "
                "FRACSEC say the clock is not synchronised (recorded instants)")

    def measure(self, k: int):
        """``measure(stat)`` of instant k, for :meth:`PlantStream.offer`."""
        return lambda stat: station_values(stat, self.magnitude[k][:, None], self.delta_rad[k][:, None],
                                           self.frequency_hz[k], self.rocof_hz_per_s[k],
                                           np.column_stack((self.p_elec_pu[k], self.battery_pu[k])))


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
        return tuple(scenario_from(load_network(case), plant).breakpoints())
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
    stream = PlantStream((host, port), args.pmu_idcode, source.names, source.rate_hz, source.nominal_hz, False,
                         FREQ_FORMAT, source.lockstep, source.header(args.recording), clock=_RecordedClock())
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
