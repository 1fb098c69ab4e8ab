"""Wireshark's C37.118 dissector (Debian's tshark) judges a real session with our PMU server.

A PDC on a loopback socket asks the server for CFG-1, CFG-2, CFG-3 and the
header, turns data on, reads 50 data frames and turns data off. The bytes
both ways, in the order they went, are written to a pcap as one TCP
connection on port 4712 (writing it ourselves needs no capture privilege),
and tshark, told ``-d tcp.port==4712,synphasor``, must find every frame with
a good checksum, none malformed, and the right count of each type.
tshark comes from ``scripts/system-deps`` (run by ``scripts/test``).
"""

from __future__ import annotations

import shutil
import socket
import struct
import subprocess
from collections import Counter

import pytest

from c37118_cases import EPOCH_NS, plant_config, plant_values
from nni_msgs_adapter.c37118 import frames as c37
from nni_msgs_adapter.c37118.server import PmuServer

PMU_PORT, PDC_PORT = 4712, 50712
DATA_FRAMES = 50
_SEGMENT_BYTES = 1460


def _read_frame(sock: socket.socket) -> bytes:
    frame = b""
    while len(frame) < 4 or len(frame) < struct.unpack(">H", frame[2:4])[0]:
        need = 4 - len(frame) if len(frame) < 4 else struct.unpack(">H", frame[2:4])[0] - len(frame)
        chunk = sock.recv(need)
        assert chunk, "the server closed the connection"
        frame += chunk
    return frame


def record_session() -> list[tuple[bool, bytes]]:
    """(from the PDC?, bytes) in the order they went, of one session with a 10-station server."""
    config = plant_config(10)
    talk = []
    with PmuServer(config, "10-generator test plant", port=0) as server, \
            socket.create_connection(server.address, timeout=5) as sock:
        def ask(command: c37.Command, replies: int) -> None:
            request = c37.encode_command(config.idcode, command, EPOCH_NS)
            sock.sendall(request)
            talk.append((True, request))
            talk.extend((False, _read_frame(sock)) for _ in range(replies))

        for command in (c37.Command.SEND_CFG1, c37.Command.SEND_CFG2, c37.Command.SEND_CFG3,
                        c37.Command.SEND_HEADER):
            ask(command, 1)
        ask(c37.Command.DATA_ON, 0)
        while server.counters()["pdcs"][0]["data_on"] is False:
            pass
        for k in range(DATA_FRAMES):
            server.offer(EPOCH_NS + k * 20_000_000, plant_values(10, k))
            talk.append((False, _read_frame(sock)))
        ask(c37.Command.DATA_OFF, 0)
    return talk


def _ipv4_checksum(header: bytes) -> int:
    total = sum(struct.unpack(">10H", header))
    total = (total & 0xFFFF) + (total >> 16)
    return ~((total & 0xFFFF) + (total >> 16)) & 0xFFFF


def _packet(from_pdc: bool, seq: int, ack: int, flags: int, payload: bytes = b"") -> bytes:
    src, dst = (b"\x7f\x00\x00\x02", b"\x7f\x00\x00\x01") if from_pdc else (b"\x7f\x00\x00\x01", b"\x7f\x00\x00\x02")
    ports = (PDC_PORT, PMU_PORT) if from_pdc else (PMU_PORT, PDC_PORT)
    tcp = struct.pack(">HHIIBBHHH", *ports, seq, ack, 5 << 4, flags, 65535, 0, 0)
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(tcp) + len(payload), 0, 0x4000, 64, 6, 0, src, dst)
    ip = ip[:10] + struct.pack(">H", _ipv4_checksum(ip)) + ip[12:]
    return bytes(12) + b"\x08\x00" + ip + tcp + payload


def write_pcap(path, talk) -> None:
    """One TCP connection (handshake, then each side's bytes in order, in segments of at most 1460 bytes)."""
    syn, ack, psh = 0x02, 0x10, 0x08
    seq = {True: 1000, False: 5000}
    packets = [_packet(True, seq[True] - 1, 0, syn), _packet(False, seq[False] - 1, seq[True], syn | ack),
               _packet(True, seq[True], seq[False], ack)]
    for from_pdc, data in talk:
        for at in range(0, len(data), _SEGMENT_BYTES):
            segment = data[at:at + _SEGMENT_BYTES]
            packets.append(_packet(from_pdc, seq[from_pdc], seq[not from_pdc], psh | ack, segment))
            seq[from_pdc] += len(segment)
    with open(path, "wb") as pcap:
        pcap.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))
        for k, packet in enumerate(packets):
            pcap.write(struct.pack("<IIII", 1_700_000_000, k * 1000, len(packet), len(packet)) + packet)


def tshark(*args) -> str:
    result = subprocess.run(["tshark", *args], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_tshark_decodes_a_session_with_no_malformed_frame_and_the_right_count_of_each_type(tmp_path):
    assert shutil.which("tshark"), "tshark is missing: scripts/system-deps installs it (scripts/test runs it)"
    talk = record_session()
    capture = tmp_path / "session.pcap"
    write_pcap(capture, talk)
    decode = ["-r", str(capture), "-d", f"tcp.port=={PMU_PORT},synphasor"]
    rows = tshark(*decode, "-Y", "synphasor", "-T", "fields", "-E", "occurrence=a", "-E", "aggregator=;",
                  "-e", "synphasor.frtype", "-e", "synphasor.checksum.status", "-e", "synphasor.command")
    types, checks, commands = Counter(), Counter(), Counter()
    for row in rows.splitlines():
        frame_types, statuses, cmds = row.split("\t")
        types.update(int(t, 0) for t in frame_types.split(";"))
        checks.update(int(c, 0) for c in statuses.split(";"))
        commands.update(int(c, 0) for c in cmds.split(";") if c)
    # tshark numbers frame types as SYNC does: 0 data, 1 header, 2 CFG-1, 3 CFG-2, 4 command, 5 CFG-3.
    assert types == {0: DATA_FRAMES, 1: 1, 2: 1, 3: 1, 4: 6, 5: 1}
    assert checks == {1: DATA_FRAMES + 10}  # 1: checksum good
    assert commands == {1: 1, 2: 1, 3: 1, 4: 1, 5: 1, 6: 1}
    assert tshark(*decode, "-Y", "_ws.malformed || _ws.expert.severity >= error || synphasor.data.unknown") == ""
    # The data frames were dissected with the configuration: 10 stations, 3 phasors each, the frequency back.
    detail = tshark(*decode, "-Y", "synphasor.frtype == 0", "-T", "fields", "-e", "synphasor.actual_frequency_value")
    first = [float(f) for f in detail.splitlines()[0].split(",")]
    # tshark prints six significant digits: 50.0084 for 50.008415.
    assert first == pytest.approx(list(plant_values(10, 0).frequency_hz), abs=5e-5)
