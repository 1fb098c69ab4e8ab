"""The command line of a served C37.118.2 stream, one definition for ``nni-demo`` and ``nni-replay``.

``--pmu-server [HOST:]PORT``, ``--pmu-idcode N`` and ``--pmu-wait-for-pdcs N``
(:func:`add_pmu_options`), checked before anything starts
(:func:`checked_stream`: the address, the IDCODE, the count of PDCs, and
the reporting rate and nominal frequency C37.118 allows; the options that
need ``--pmu-server`` refused without it), and the line that ends a served
run with the stream's counters (:func:`summary_line`).

Pure python: no ROS import.
"""

from __future__ import annotations

from nni_msgs_adapter.c37118.profile import check_stream_rate, parse_server_address
from nni_msgs_adapter.ros.cli_support import CliError

#: Options that apply only with ``--pmu-server``.
STREAM_OPTIONS = ("--pmu-idcode", "--pmu-wait-for-pdcs")
#: PDCs a stream may be asked to wait for (the server's client limit).
MAX_WAIT_FOR_PDCS = 64


def add_pmu_options(parser, served: str, start: str) -> None:
    """``--pmu-server``, ``--pmu-idcode``, ``--pmu-wait-for-pdcs``: ``served`` says what the stream carries
    (``every run's PMU measurements``), ``start`` what waits for the PDCs (``each run``)."""
    group = parser.add_argument_group("C37.118.2 PMU stream (for a PDC: pyc37, openPDC, Wireshark)")
    group.add_argument("--pmu-server", metavar="[HOST:]PORT", default=None,
                       help=f"serve {served} as an IEEE C37.118.2 stream over TCP at HOST:PORT "
                            "(HOST: 127.0.0.1 unless named, 0.0.0.0 for every interface; PORT 0: a free one, "
                            "printed; 4712 is customary); one station per generator; default: none")
    group.add_argument("--pmu-idcode", type=int, default=1, metavar="N",
                       help="the stream's IDCODE, 1..65534 (stations 1..N, one per generator; default: 1)")
    group.add_argument("--pmu-wait-for-pdcs", type=int, default=0, metavar="N",
                       help=f"start {start} only once N PDCs have turned data on, 0..{MAX_WAIT_FOR_PDCS} "
                            "(default: 0, no wait)")


def refuse_without_server(args, words) -> None:
    """CliError when ``words`` (the command line) give an option of :data:`STREAM_OPTIONS` without ``--pmu-server``."""
    if args.pmu_server is None:
        given = [word for word in words if word.split("=", 1)[0] in STREAM_OPTIONS]
        if given:
            raise CliError(f"{given[0].split('=', 1)[0]} applies to a C37.118 stream only (--pmu-server [HOST:]PORT)")


def checked_stream(args, rate_hz: float, nominal_hz: float, option: str = "--pmu-server") -> tuple[str, int]:
    """``(host, port)`` of ``--pmu-server`` (loopback, a free port, when not given), once the IDCODE, the count
    of PDCs to wait for, the reporting rate and the nominal frequency are ones a stream can have; CliError (one
    line, naming ``option`` for the address and the rate) otherwise."""
    try:
        host, port = parse_server_address(args.pmu_server) if args.pmu_server is not None else ("127.0.0.1", 0)
        check_stream_rate(rate_hz, nominal_hz)
    except ValueError as error:
        raise CliError(f"{option}: {error}") from None
    if not 1 <= args.pmu_idcode <= 65534:
        raise CliError(f"--pmu-idcode must be within 1..65534, got {args.pmu_idcode}")
    if not 0 <= args.pmu_wait_for_pdcs <= MAX_WAIT_FOR_PDCS:
        raise CliError(f"--pmu-wait-for-pdcs must be within 0..{MAX_WAIT_FOR_PDCS}, got {args.pmu_wait_for_pdcs}")
    return host, port


def summary_line(stream: dict) -> str:
    """``C37.118 stream 127.0.0.1:4712: 500 frames offered; PDC 127.0.0.1:5120 sent 502, dropped 0`` of a
    stream's summary (:meth:`nni_plant_sim.pmu_stream.PlantStream.summary`)."""
    pdcs = "; ".join(f"PDC {pdc['address']} sent {pdc['frames_sent']}, dropped {pdc['frames_dropped']}"
                     for pdc in stream["pdcs"]) or "no PDC connected"
    return f"  C37.118 stream {stream['address']}: {stream['offered']} frames offered; {pdcs}"
