"""The demos' IEEE C37.118.2 stream (``nni-demo --pmu-server``, ``nni-demo --case ... --pmu-server``).

The options (where the plant's PMU stream listens, its IDCODE, how many PDCs
a run waits for: :mod:`nni_msgs_adapter.c37118.cli`, as ``nni-replay``'s),
checked before anything starts, become the plant's stream parameters. While a run goes
on, :class:`StreamWatch` follows the plant's log: the address it listens on
(port 0: the one it picked) and one progress line per PDC that connects,
turns data on or off, or goes away; after it, the stream's counters from the
plant's final line (:data:`nni_plant_sim.pmu_stream.SUMMARY_PREFIX_STREAM`),
printed by :func:`~nni_msgs_adapter.c37118.cli.summary_line`. Each run has its own
plant and so its own server: a PDC connected to one run is closed at its end.
"""

from __future__ import annotations

import json

from nni_battery_controller import demo_c37118
from nni_msgs_adapter.c37118 import cli
from nni_msgs_adapter.ros.cli_support import CliError
from nni_msgs_adapter.ros.processes import ChildError
from nni_plant_sim.pmu_stream import SUMMARY_PREFIX_STREAM

#: Seconds a plant gets to say where its stream listens.
LISTEN_WAIT_S = 30.0
#: What the plant's log says once its stream listens (:meth:`.PlantStream.start`), and before each event.
LISTENING_PREFIX, LISTENING_TEXT, EVENT_TEXT = "C37.118 PMU stream", " listening on ", "C37.118: "


def add_pmu_options(parser) -> None:
    """``--pmu-server``, ``--pmu-idcode``, ``--pmu-wait-for-pdcs`` of the SMIB and the network demo."""
    cli.add_pmu_options(parser, "every run's PMU measurements", "each run")


def stream_parameters(args, words, nominal_hz: float) -> dict:
    """The plant parameters of the stream ``args`` ask for: ``--pmu-server``'s, or ``--measurements c37118``'s
    (:func:`.demo_c37118.plant_parameters`: a free loopback port, unless ``--pmu-server`` names one, the client
    one more PDC to wait for); empty for neither. CliError for an option that needs ``--pmu-server`` without it,
    a bad address, IDCODE or count, or a rate C37.118 does not allow at ``nominal_hz``."""
    through_client = args.measurements == "c37118"
    cli.refuse_without_server(args, words)
    if args.pmu_server is None and not through_client:
        return {}
    host, port = cli.checked_stream(args, args.rate, nominal_hz,
                                    "--pmu-server" if args.pmu_server is not None else "--measurements c37118")
    return {"pmu_host": host, "pmu_port": port, "pmu_idcode": args.pmu_idcode,
            "pmu_wait_for_pdcs": args.pmu_wait_for_pdcs,
            **demo_c37118.plant_parameters(args.measurements, port, host, args.pmu_wait_for_pdcs)}


def wait_text(args) -> str:
    """How the header line states the stream, or empty without one."""
    if args.pmu_server is None:
        return ""
    wait = f", each run waits for {args.pmu_wait_for_pdcs} PDC(s)" if args.pmu_wait_for_pdcs else ""
    return f"C37.118 PMU stream IDCODE {args.pmu_idcode} at {args.pmu_server}{wait}"


class StreamWatch:
    """One run's stream as its plant logs it: :meth:`listening`, :meth:`follow` while the run goes on,
    :meth:`summary` after it. Prints with two spaces of indent, as the demos' run lines."""

    def __init__(self, plant):
        self._plant = plant
        self._seen = 0

    def listening(self, announce: bool = True) -> str:
        """Wait for the plant to listen; return where (``host:port``), printed if ``announce``. CliError if it
        cannot."""
        try:
            line = self._plant.wait_for_line(LISTENING_PREFIX, LISTEN_WAIT_S, lambda text: LISTENING_TEXT in text)
        except ChildError:
            raise CliError(f"the plant's C37.118 stream did not listen within {LISTEN_WAIT_S:g} s: "
                           f"{self._plant.tail()}") from None
        where = line.rsplit(LISTENING_TEXT, 1)[1].strip()
        if announce:
            print(f"  C37.118 stream listening on {where}", flush=True)
        return where

    def follow(self) -> list[str]:
        """The stream's events the plant logged since the last call (a PDC came, turned data on, went), as lines
        to print."""
        lines = self._plant.output().split("\n")[:-1]  # whole lines only: the last may be half written
        events = [f"  {line[line.index(EVENT_TEXT):]}" for line in lines[self._seen:] if EVENT_TEXT in line]
        self._seen = len(lines)
        return events

    def summary(self) -> dict:
        """The stream's final counters: the plant's last line for them, once it has exited."""
        for line in self._plant.output().splitlines():
            if line.startswith(SUMMARY_PREFIX_STREAM):
                return json.loads(line[len(SUMMARY_PREFIX_STREAM):])
        raise CliError("the plant did not report its C37.118 stream's counters")
