"""Count the UDP datagrams that reach a network namespace: ``python tests/udp_sniffer.py``.

Run inside a namespace (``ip netns exec``; needs root for the packet socket),
it prints ``sniffer ready`` once it captures, then records every IPv4 UDP
datagram that arrives on any interface of that namespace except ``lo``. On
SIGINT or SIGTERM it prints one JSON line: per interface, how many datagrams
arrived, how many of them carry RTPS (DDS; the payload starts with ``RTPS``),
and their (source, destination) addresses. The multi-host test runs it on a
decoy link beside the one the loop is meant to use.
"""

from __future__ import annotations

import json
import signal
import socket
import sys

READY = "sniffer ready"
REPORT_PREFIX = "sniffer report: "
#: Linux: every protocol, network byte order (``ETH_P_ALL``).
_ETH_P_ALL = 0x0003
_ETHERTYPE_IPV4 = 0x0800
_UDP = 17
_ETHERNET_HEADER = 14
_UDP_HEADER = 8


def main() -> None:
    capture = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(_ETH_P_ALL))
    capture.settimeout(0.1)
    stop = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda number, frame: stop.append(number))
    report: dict[str, dict] = {}
    print(READY, flush=True)
    while not stop:
        try:
            frame, (interface, ethertype, packet_type, *_) = capture.recvfrom(65535)
        except (TimeoutError, InterruptedError):
            continue
        if interface == "lo" or ethertype != _ETHERTYPE_IPV4 or packet_type == socket.PACKET_OUTGOING:
            continue
        ip = frame[_ETHERNET_HEADER:]
        if len(ip) < 20 or ip[9] != _UDP:
            continue
        payload = ip[4 * (ip[0] & 0x0F) + _UDP_HEADER:]
        seen = report.setdefault(interface, {"datagrams": 0, "rtps": 0, "pairs": []})
        seen["datagrams"] += 1
        seen["rtps"] += payload[:4] == b"RTPS"
        pair = [socket.inet_ntoa(ip[12:16]), socket.inet_ntoa(ip[16:20])]
        if pair not in seen["pairs"]:
            seen["pairs"].append(pair)
    print(REPORT_PREFIX + json.dumps(report), flush=True)


if __name__ == "__main__":
    sys.exit(main())
