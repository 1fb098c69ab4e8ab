"""``python -m bench`` (or ``bench/run_all``): run every benchmark and write BENCHMARKS.md.

Each table sets a measurement beside a baseline taken in the same run:

1. closed-loop latency (plant -> controller -> plant, realtime mode) at 50, 100,
   500 and 1000 measurements/s beside a bare rclpy ping-pong of the same message
   type and QoS in two processes, in alternating rounds;
   1b. the controller's share of it: the same timed ping answered in
   alternate rounds by the bare echo and by the controller node itself;
2. lockstep throughput (simulated s per wall s) of the paper's case at 50 and
   100 samples/s beside its floor, the samples times a chained ping-pong's
   round trip, in alternating rounds;
3. the region-of-attraction sweep, 200 x 200 x 4, vectorised, beside the
   per-trajectory scipy solve_ivp loop (``simulate_continuous``) on a subsample,
   extrapolated, with the fraction of cells where the two disagree;
4. network lockstep throughput (issue 14) of the network plant node with one
   controller process per generator for N = 1 (the SMIB plant node), 4
   (kundur_two_area) and 10 (ieee39) beside a chained fan-out ping-pong to N
   echo processes, and with the controllers composed in one process for N =
   10 and 52 (kundur_ring_52) beside a chained fan-out to N echo nodes
   composed in one process, in alternating rounds, and the cost per added
   generator of each deployment;
5. network realtime at 50 frames/s, ieee39's 10 controllers as separate
   processes and composed in one, per generator beside the timed fan-out to
   echoes deployed alike;
6. memory (and CPU) per controller process and per composed controller;
7. where a network lockstep sample's CPU time goes, per part of the plant's
   step and of the composed controllers' process (py-spy from outside);
8. the latency the C37.118 path adds to the loop, beside the ROS-fed loop;
9. the cost per sample of authenticated battery commands: the controller's
   HMAC-SHA256 seal and the plant's check, beside the bare publish;
10. the C37.118 PMU server's frames/s for 1, 10 and 52 stations beside a bare
    socket-send floor of the same bytes, and its reporting latency (sample
    instant to arrival at a PDC process) at 50 frames/s;
11. the contingency screen (``nni-simulate --case --screen``): IEEE 39's bus
    faults x 4 b serial beside a 2-worker LocalCluster (speed-up, task
    overhead share), contingencies per second for IEEE 39, 118 and 300, the
    full IEEE 39 N-1 screen, and one contingency's bisection beside ANDES';
12. the SMIB lockstep loop with a Foxglove bridge and a client that never
    reads, beside the same loop alone (alternating rounds);
13. ``nni-simulate --compare-laws`` on the SMIB beside the same trajectories
    integrated one at a time by scipy's solve_ivp, and the network
    comparisons' (Kundur, IEEE 39) wall time;
14. every bus fault of IEEE 118 and 300 at b 0 and 0.3 on a 2-worker
    LocalCluster: the screens' time and their weakest contingencies (about
    an hour of a full run).

``--only`` reruns some: their sections replace their namesakes in the page
(``--out``) and every other section stays as the earlier run wrote it.

Node processes are started exactly as ``nni-demo`` starts them; discovery stays
on localhost (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) in a ROS domain of the
benchmark's own (``--domain-id``, default 87). ``--quick`` shortens everything
for development; its numbers are not the ones to publish.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from bench.command_auth import bench_command_auth
from bench.foxglove import bench_foxglove
from bench.common import NETWORK_RATE_HZ, ROOT
from bench.c37118_loop import bench_c37118_loop
from bench.c37118_server import FRAMES as C37118_SERVER_FRAMES, bench_c37118_server
from bench.law_comparison import bench_law_comparison
from bench.latency import bench_controller_share, bench_latency
from bench.lockstep import bench_lockstep
from bench.machine import machine_description
from bench.network_lockstep import NETWORK_LOCKSTEP_CASES, NETWORK_LOCKSTEP_QUICK_CASES, bench_network_lockstep
from bench.network_profile import PROFILE_QUICK_RUN, PROFILE_RUN, bench_network_profile
from bench.network_realtime import bench_network_realtime
from bench.report import report, splice
from bench.roa import bench_roa
from bench.screening import ANDES_PYTHON, bench_large_screens, bench_screening
from nni_msgs_adapter.ros.command_auth import KEY_FILE_ENV, run_key
from nni_msgs_adapter.ros.processes import ChildError

#: Alternating (baseline, loop) rounds of a full run (latency and lockstep per rate, network realtime); the
#: duration is split among them, except network realtime: 30 s per round, as issue 23 asks.
ROUNDS = 3
#: What --only selects (all by default).
BENCHMARKS = ("latency", "lockstep", "roa", "network-lockstep", "network-realtime", "network-profile", "c37118-loop",
              "command-auth", "c37118-server", "screening", "foxglove", "law-comparison", "screening-large")


def parse_args(argv=None):
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="short runs (development; not for publishing)")
    parser.add_argument("--only", nargs="+", choices=BENCHMARKS, default=list(BENCHMARKS),
                        help="run only these benchmarks")
    parser.add_argument("--out", type=Path, default=ROOT / "BENCHMARKS.md", help="report path (default BENCHMARKS.md)")
    parser.add_argument("--domain-id", type=int, default=87, help="ROS_DOMAIN_ID of the benchmark (default 87)")
    parser.add_argument("--rates", type=float, nargs="+", default=[50.0, 100.0, 500.0, 1000.0],
                        help="latency benchmark rates, measurements/s")
    parser.add_argument("--andes-python", type=Path, default=ANDES_PYTHON,
                        help=f"the python of a venv with ANDES (screening's comparison; default {ANDES_PYTHON})")
    args = parser.parse_args(argv)
    if not 0 <= args.domain_id <= 232:
        parser.error(f"ROS domain id must be within 0..232, got {args.domain_id}")
    return args


def run_benchmarks(env: dict, log_root: Path, only, quick: bool, rates, domain_id: int,
                   andes_python: Path = ANDES_PYTHON) -> dict:
    """Each benchmark ``only`` names, with the durations of a full run (or ``quick``'s); results by report section."""
    duration_s = 6.0 if quick else 30.0
    results = {}
    if "latency" in only:
        results["latency"] = bench_latency(env, log_root, rates, duration_s, ROUNDS)
        results["controller-share"] = bench_controller_share(env, log_root, 100.0, 4, 3.0 if quick else 15.0)
    if "lockstep" in only:
        results["lockstep"] = bench_lockstep(env, log_root, [50.0, 100.0], 30.0 if quick else 60.0,
                                             600 if quick else 6000, ROUNDS)
    if "roa" in only:
        results["roa"] = bench_roa(40 if quick else 200)
    if "network-lockstep" in only:
        results["network-lockstep"] = bench_network_lockstep(
            env, log_root, NETWORK_LOCKSTEP_QUICK_CASES if quick else NETWORK_LOCKSTEP_CASES, NETWORK_RATE_HZ,
            4.0 if quick else 30.0, 200 if quick else 1500)
    if "network-realtime" in only:
        results["network-realtime"] = bench_network_realtime(
            env, log_root, "kundur_two_area" if quick else "ieee39", NETWORK_RATE_HZ, 5.0 if quick else 30.0,
            1 if quick else ROUNDS)
    if "network-profile" in only:
        results["network-profile"] = bench_network_profile(env, log_root, PROFILE_QUICK_RUN if quick else PROFILE_RUN)
    if "c37118-loop" in only:
        results["c37118-loop"] = bench_c37118_loop(env, log_root, 50.0, duration_s, ROUNDS)
    if "command-auth" in only:
        results["command-auth"] = bench_command_auth(domain_id)
    if "c37118-server" in only:
        results["c37118-server"] = bench_c37118_server(
            env, C37118_SERVER_FRAMES // 10 if quick else C37118_SERVER_FRAMES, 5.0 if quick else duration_s)
    if "screening" in only:
        results["screening"] = bench_screening(quick, andes_python)
    if "screening-large" in only:
        results["screening-large"] = bench_large_screens(quick)
    if "foxglove" in only:
        results["foxglove"] = bench_foxglove(env, log_root, 10.0 if quick else 30.0, 3 if quick else 5,
                                             5.0 if quick else 10.0)
    if "law-comparison" in only:
        results["law-comparison"] = bench_law_comparison(quick)
    return results


def main(argv=None) -> int:
    args = parse_args(argv)
    command = "bench/run_all" + (" " + " ".join(sys.argv[1:] if argv is None else argv)).rstrip()
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(args.domain_id),
                      PYTHONUNBUFFERED="1")
    log_root = ROOT / "out" / "bench"
    started_text, started = time.strftime("%Y-%m-%d %H:%M %Z"), time.monotonic()
    machine = machine_description(args.domain_id)
    with run_key() as key:  # the plants and controllers authenticate their commands as nni-demo's do
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
                   **{KEY_FILE_ENV: str(key)})
        results = run_benchmarks(env, log_root, args.only, args.quick, args.rates, args.domain_id,
                                 args.andes_python)
    machine["load_average_at_end"] = os.getloadavg()
    text = report(command, machine, args.quick, results, started_text, time.monotonic() - started)
    if set(args.only) != set(BENCHMARKS) and args.out.exists():
        text = splice(args.out.read_text(), text, command, started_text)
    tmp = args.out.with_name(args.out.name + ".part")
    tmp.write_text(text)
    tmp.replace(args.out)
    print(text)
    print(f"wrote {args.out} (logs in {log_root})", file=sys.stderr)
    return 0


def run(argv=None) -> int:
    """``main``, with a benchmark that cannot run (a child that failed or stayed silent) as one line and exit 1."""
    try:
        return main(argv)
    except (ChildError, RuntimeError) as error:
        print(f"bench: error: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(run())
