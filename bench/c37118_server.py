"""Section 10 (issue 22): frames per second the C37.118 PMU server sustains, and its reporting latency to a PDC.

Throughput, for 1, 10 and 52 stations (3 float polar phasors, 1 analog, 1
digital word each, as the plants' streams), in one run:

* the encoding alone: ``DataFrameEncoder.encode`` per frame;
* the server: ``PmuServer.offer`` to one PDC (a thread reading a loopback
  socket after "data on") as fast as the PDC takes the frames: an offer
  waits while more than ``WINDOW`` frames are on their way (the hand-off
  and the queues would drop beyond their bounds); frames per second from the
  first offer to the PDC's last byte;
* its floor: the same frames, encoded beforehand, sent with ``sendall`` on a
  bare loopback TCP socket to the same kind of reader thread.

The floor sends frame by frame (one ``sendall``, one segment each, as a PDC
is fed at the reporting rate); the server, given frames faster than one
send each, hands up to 64 to one ``sendmsg``: below 2 kB a frame it can
beat that floor (a floor / server ratio under 1). Measured on the project's
2-core machine: 1 station 0.24, 10 stations 0.30, 52 stations 1.08 (server
165 000, 133 000 and 66 000 frames/s).

Reporting latency: the server offers a 10-station stream at 50 frames/s,
each frame stamped with its wall-clock instant on the 20 ms grid and offered
once that instant has come (as a realtime plant samples), to a PDC in
another process (``python -m bench.c37118_server --pdc PORT``: a TCP client
that turns data on, reassembles the frames and takes the wall clock at each
frame's arrival); latency = arrival - SOC/FRACSEC, the offer's own lateness
included. Target: p99 under 5 ms (C37.118.1's P-class limit is 2/Fs, 40 ms
at 50 frames/s).

``python -m bench.c37118_server [--quick]`` prints the section on its own;
``bench/run_all --only c37118-server`` writes it into BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import threading
import time

import numpy as np

from bench.common import ROOT, not_completed, percentiles_ms, printed_json, progress, verdict
from nni_msgs_adapter.c37118 import frames as c37
from nni_msgs_adapter.c37118.server import PmuServer
from nni_msgs_adapter.c37118.stream import FrameReassembler

EPOCH_NS = 1_700_000_000_000_000_000
STATION_COUNTS = (1, 10, 52)
FRAMES = 20_000
#: Frames in flight at most (offered or sent, not yet read), below the server's hand-off bound.
WINDOW = 500
#: The latency run: a 10-station stream (IEEE 39's) at 50 frames/s.
LATENCY_STATIONS, LATENCY_RATE_HZ = 10, 50
#: Issue 22's target for the reporting latency's p99, ms (C37.118.1's P-class limit at 50 frames/s: 40 ms).
LATENCY_P99_TARGET_MS = 5.0
#: The JSON line the PDC process prints at its end.
PDC_RESULT_PREFIX = "c37118 pdc result: "


def stream(n_stations: int) -> tuple[c37.Config, c37.Measurements]:
    stations = tuple(c37.Station(f"G{k}", k, (c37.PhasorChannel("EMF"), c37.PhasorChannel("V"),
                                              c37.PhasorChannel("I", is_current=True)),
                                 (c37.AnalogChannel("P battery"),), (c37.DigitalWord(("bit",) * 16),))
                     for k in range(1, n_stations + 1))
    values = c37.Measurements(stat=np.zeros(n_stations, int), magnitude=np.ones((n_stations, 3)),
                              angle_rad=np.full((n_stations, 3), 0.4), frequency_hz=np.full(n_stations, 50.0),
                              rocof_hz_per_s=np.zeros(n_stations), analog=np.zeros((n_stations, 1)),
                              digital=np.zeros((n_stations, 1), int))
    return c37.Config(1, stations, 50), values


def _reader(sock: socket.socket, total_bytes: int, done: list, progress: list) -> threading.Thread:
    def run():
        while progress[0] < total_bytes:
            chunk = sock.recv(1 << 20)
            if not chunk:
                break
            progress[0] += len(chunk)
        done.append(time.perf_counter())

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def encode_cost_s(config: c37.Config, values: c37.Measurements, frames: int) -> float:
    encoder = c37.DataFrameEncoder(config)
    start = time.perf_counter()
    for k in range(frames):
        encoder.encode(EPOCH_NS + k * 20_000_000, values)
    return (time.perf_counter() - start) / frames


def server_rate(config: c37.Config, values: c37.Measurements, frames: int) -> tuple[float, float]:
    """(frames/s delivered, mean offer s) through PmuServer to one reading PDC."""
    with PmuServer(config, "bench", port=0, queue_frames=frames + 1) as server, \
            socket.create_connection(server.address) as sock:
        sock.sendall(c37.encode_command(config.idcode, c37.Command.DATA_ON, EPOCH_NS))
        while server.counters()["commands"].get("data_on") != 1:
            time.sleep(0.001)
        done, progress, size = [], [0], config.data_frame_bytes
        reader = _reader(sock, frames * size, done, progress)
        offer_s = 0.0
        start = time.perf_counter()
        for k in range(frames):
            while k - progress[0] // size > WINDOW:
                time.sleep(0)
            before = time.perf_counter()
            server.offer(EPOCH_NS + k * 20_000_000, values)
            offer_s += time.perf_counter() - before
        reader.join(60)
        counters = server.counters()
    if counters["frames_dropped"] or counters["handoff_dropped"] or not done:
        raise RuntimeError(f"the server dropped frames: {counters}")
    return frames / (done[0] - start), offer_s / frames


def floor_rate(config: c37.Config, values: c37.Measurements, frames: int) -> float:
    """frames/s of a bare loopback sendall of the same frames, encoded beforehand."""
    encoder = c37.DataFrameEncoder(config)
    encoded = [encoder.encode(EPOCH_NS + k * 20_000_000, values) for k in range(frames)]
    with socket.create_server(("127.0.0.1", 0)) as listener:
        sender = socket.create_connection(listener.getsockname())
        receiver, _ = listener.accept()
        with sender, receiver:
            sender.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            done, progress, size = [], [0], config.data_frame_bytes
            reader = _reader(receiver, frames * size, done, progress)
            start = time.perf_counter()
            for k, frame in enumerate(encoded):
                while k - progress[0] // size > WINDOW:
                    time.sleep(0)
                sender.sendall(frame)
            reader.join(60)
    return frames / (done[0] - start)


def throughput_row(n_stations: int, frames: int) -> dict:
    """One station count: the encoding's cost, the server's rate and the bare floor's, or why it did not complete."""
    try:
        config, values = stream(n_stations)
        encode_s = encode_cost_s(config, values, frames)
        served, offer_s = server_rate(config, values, frames)
        floor = floor_rate(config, values, frames)
    except (OSError, RuntimeError) as error:
        return {"stations": n_stations, **not_completed(f"C37.118 server, {n_stations} stations", error)}
    return {"stations": n_stations, "bytes": config.data_frame_bytes, "encode_us": encode_s * 1e6,
            "offer_us": offer_s * 1e6, "server_fps": served, "floor_fps": floor, "floor_ratio": floor / served}


def reporting_latency(env: dict, duration_s: float) -> dict:
    """A PDC process reads the 50 frames/s stream for ``duration_s``: arrival - sample instant, percentiles (ms)."""
    config, values = stream(LATENCY_STATIONS)
    config = c37.Config(config.idcode, config.stations, LATENCY_RATE_HZ)
    frames = round(duration_s * LATENCY_RATE_HZ)
    period_ns = 1_000_000_000 // LATENCY_RATE_HZ
    with PmuServer(config, "bench", port=0) as server:
        pdc = subprocess.Popen([sys.executable, "-m", "bench.c37118_server", "--pdc", str(server.address[1]),
                                "--frames", str(frames)], env=env, cwd=ROOT, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 30.0
            while not server.streaming:
                if time.monotonic() > deadline or pdc.poll() is not None:
                    raise RuntimeError(f"the PDC process did not turn data on: {pdc.stderr.read()[-300:]}")
                time.sleep(0.01)
            start_ns = (time.time_ns() // period_ns + 5) * period_ns  # on the grid, 100 ms ahead
            late_ns = []
            for k in range(frames):
                instant_ns = start_ns + k * period_ns
                wait_ns = instant_ns - time.time_ns()
                if wait_ns > 0:
                    time.sleep(wait_ns * 1e-9)
                late_ns.append(time.time_ns() - instant_ns)
                server.offer(instant_ns, values)
            out, err = pdc.communicate(timeout=30.0)
        finally:
            if pdc.poll() is None:
                pdc.kill()
                pdc.wait()
        counters = server.counters()
    result = printed_json(out, PDC_RESULT_PREFIX)
    if pdc.returncode != 0 or result is None:
        raise RuntimeError(f"the PDC process exited with {pdc.returncode}: {err.strip()[-300:]}")
    return {"stations": LATENCY_STATIONS, "rate_hz": LATENCY_RATE_HZ, "duration_s": duration_s, "frames": frames,
            **result, "offer_late_ms": percentiles_ms(late_ns), "frames_dropped": counters["frames_dropped"]}


def bench_c37118_server(env: dict, frames: int, latency_duration_s: float) -> dict:
    """Section 10's results: a throughput row per station count, the reporting latency (or why not completed)."""
    progress(f"C37.118 server: {frames} frames per station count {', '.join(map(str, STATION_COUNTS))}, then "
             f"{latency_duration_s:g} s at {LATENCY_RATE_HZ} frames/s to a PDC process")
    rows = [throughput_row(n, frames) for n in STATION_COUNTS]
    try:
        latency = reporting_latency(env, latency_duration_s)
    except (OSError, RuntimeError, subprocess.TimeoutExpired) as error:
        latency = not_completed("C37.118 reporting latency", error)
    return {"frames": frames, "rows": rows, "latency": latency}


def c37118_server_section(result: dict) -> list[str]:
    """Section 10: the server's frames/s beside the bare send floor; the reporting latency against its target."""
    lines = ["## 10. C37.118 PMU server: frames per second and reporting latency", "",
             f"Throughput: {result['frames']} data frames per station count (3 float polar phasors, 1 analog, "
             "1 digital word per station) offered to one PDC over loopback as fast as it reads them, beside the "
             "floor: the same frames, encoded beforehand, each sent with one `sendall` on a bare TCP socket. "
             "Floor / server under 1: the server batches queued frames into one `sendmsg`.", "",
             "| stations | frame bytes | encode (us) | offer (us) | server (frames/s) | floor (frames/s) | "
             "floor / server |", "|---:|---:|---:|---:|---:|---:|---:|"]
    for row in result["rows"]:
        if "error" in row:
            lines.append(f"| {row['stations']} | **not completed**: {row['error']} | | | | | |")
        else:
            lines.append(f"| {row['stations']} | {row['bytes']} | {row['encode_us']:.1f} | {row['offer_us']:.1f} | "
                         f"{row['server_fps']:.0f} | {row['floor_fps']:.0f} | {row['floor_ratio']:.2f} |")
    latency = result["latency"]
    lines += [""]
    if "error" in latency:
        return lines + [f"Reporting latency: **not completed**: {latency['error']}", ""]
    ok = latency["p99"] < LATENCY_P99_TARGET_MS
    return lines + [
        f"Reporting latency: {latency['stations']} stations at {latency['rate_hz']} frames/s for "
        f"{latency['duration_s']:g} s, each frame offered at its sample's wall-clock instant, read by a PDC in "
        "another process over loopback (TCP, data on); latency = arrival - SOC/FRACSEC, the offer's own lateness "
        "included.", "",
        "| frames offered / read | p50 (ms) | p99 (ms) | max (ms) | offer late p50 / p99 (ms) | dropped |",
        "|---:|---:|---:|---:|---:|---:|",
        f"| {latency['frames']} / {latency['received']} | {latency['p50']:.3f} | {latency['p99']:.3f} | "
        f"{latency['max']:.2f} | {latency['offer_late_ms']['p50']:.3f} / {latency['offer_late_ms']['p99']:.3f} | "
        f"{latency['frames_dropped']} |", "",
        f"p99 **{latency['p99']:.3f} ms** < {LATENCY_P99_TARGET_MS:g} ms (C37.118.1 P class allows 2/Fs = "
        f"{2000 / latency['rate_hz']:g} ms): {verdict(ok)}.", ""]


def run_pdc(port: int, frames: int) -> int:
    """The PDC process: data on, then each data frame's arrival - its instant, until ``frames`` or the close."""
    latencies, reader = [], FrameReassembler()
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.sendall(c37.encode_command(1, c37.Command.DATA_ON, time.time_ns()))
        while len(latencies) < frames:
            data = sock.recv(1 << 16)
            arrival_ns = time.time_ns()
            if not data:
                break
            for frame in reader.feed(data):
                head = c37.read_head(frame)
                if head.frame_type == c37.FrameType.DATA:
                    latencies.append(arrival_ns - c37.instant_ns_from(head.soc, head.fraction, c37.DEFAULT_TIME_BASE))
    if not latencies:
        print("no data frame arrived", file=sys.stderr)
        return 1
    print(PDC_RESULT_PREFIX + json.dumps({"received": len(latencies), **percentiles_ms(latencies)}), flush=True)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.c37118_server", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a tenth of the frames, 5 s of latency (not to publish)")
    parser.add_argument("--pdc", type=int, metavar="PORT", help="be the latency run's PDC process (bench-internal)")
    parser.add_argument("--frames", type=int, default=0, help="with --pdc: the data frames to read")
    args = parser.parse_args(argv)
    if args.pdc is not None:
        return run_pdc(args.pdc, args.frames)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    result = bench_c37118_server(env, FRAMES // 10 if args.quick else FRAMES, 5.0 if args.quick else 30.0)
    print("\n".join(c37118_server_section(result)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
