"""``python -m bench.c37118_server``: frames per second the C37.118 PMU server sustains to one PDC.

For 1, 10 and 52 stations (3 float polar phasors, 1 analog, 1 digital word
each, as the plants' streams), in one run:

* the encoding alone: ``DataFrameEncoder.encode`` per frame;
* the server: ``PmuServer.offer`` to one PDC (a thread reading a loopback
  socket after "data on") as fast as the PDC takes the frames: an offer
  waits while more than ``WINDOW`` frames are on their way (the hand-off
  and the queues would drop beyond their bounds); frames per second from the
  first offer to the PDC's last byte;
* its floor: the same frames, encoded beforehand, sent with ``sendall`` on a
  bare loopback TCP socket to the same kind of reader thread.

Printed: each rate and the floor / server ratio (the server's cost of
encoding, hand-off and its I/O thread over a bare send of the same bytes).
The floor sends frame by frame (one ``sendall``, one segment each, as a PDC
is fed at the reporting rate); the server, given frames faster than one
send each, hands up to 64 to one ``sendmsg``: below 2 kB a frame it can
beat that floor (a ratio under 1). Measured on the project's 2-core machine:
1 station 0.24, 10 stations 0.30, 52 stations 1.08 (server 165 000, 133 000
and 66 000 frames/s).
``--quick`` runs a tenth of the frames, for development.
"""

from __future__ import annotations

import argparse
import socket
import sys
import threading
import time

import numpy as np

from nni_msgs_adapter.c37118 import frames as c37
from nni_msgs_adapter.c37118.server import PmuServer

EPOCH_NS = 1_700_000_000_000_000_000
STATION_COUNTS = (1, 10, 52)
FRAMES = 20_000
#: Frames in flight at most (offered or sent, not yet read), below the server's hand-off bound.
WINDOW = 500


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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.c37118_server", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a tenth of the frames (numbers not to publish)")
    args = parser.parse_args(argv)
    frames = FRAMES // 10 if args.quick else FRAMES
    print(f"C37.118 PMU server to one PDC over loopback, {frames} frames per case")
    print(f"{'stations':>8} {'bytes':>6} {'encode us':>10} {'offer us':>9} {'server fr/s':>12} {'floor fr/s':>11}"
          f" {'floor/server':>12}")
    for n_stations in STATION_COUNTS:
        config, values = stream(n_stations)
        encode_s = encode_cost_s(config, values, frames)
        served, offer_s = server_rate(config, values, frames)
        floor = floor_rate(config, values, frames)
        print(f"{n_stations:>8} {config.data_frame_bytes:>6} {encode_s * 1e6:>10.1f} {offer_s * 1e6:>9.1f}"
              f" {served:>12.0f} {floor:>11.0f} {floor / served:>12.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
