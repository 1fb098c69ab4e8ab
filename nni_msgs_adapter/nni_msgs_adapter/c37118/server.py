"""The PMU side of C37.118.2 over TCP: one data stream served to any PDCs, none of which can slow its source.

:class:`PmuServer` listens on ``host:port`` (loopback by default; port 0
picks a free port, :attr:`PmuServer.address` tells which) and serves one
stream (one :class:`~.frames.Config`) to every PDC that connects, each with
its own state:

* commands honoured (CMD 1 data off, 2 data on, 3 header, 4/5/6 CFG-1/2/3;
  8, an extended frame, is counted and ignored); data flows to a PDC only
  after its "data on". A command whose IDCODE is not the stream's, a frame
  that is not a command, an unknown CMD code and every bad frame of the
  command stream (see :mod:`.stream`) are counted under ``rejected`` by
  reason and change nothing; a command that asks for the state the PDC is
  already in (a second "data on", "data off" before any "data on") is
  counted ``redundant`` and changes nothing either.
* :meth:`PmuServer.offer` is called from the plant's thread with a sample; it
  encodes the data frame there (when at least one PDC has data on) and hands
  it to the server's own I/O thread through a deque and one wake-up byte:
  it never blocks and takes a few microseconds beyond the encoding.
* each PDC has a send queue bounded to ``queue_frames`` frames; a PDC that
  stalls or never reads fills its kernel socket buffer (fixed at
  ``SEND_BUFFER_BYTES``), then its queue, and
  from then on its oldest queued frames are dropped, for it alone, and
  counted ``frames_dropped``. A PDC that goes away is forgotten (its
  counters go to the totals). At most ``max_clients`` PDCs at once; more are
  closed at once and counted ``refused``.
* :meth:`PmuServer.counters` gives totals and per-PDC counters as a dict
  (for /diagnostics; those of the last ``DEPARTED_KEPT`` PDCs that went away
  too); :meth:`PmuServer.events` gives the lines to log (a PDC connected,
  went away with what it was sent and lost, turned data on or off, with its
  address).
* configuration and header frames are stamped with ``clock_ns()`` when sent;
  data frames with their sample's instant.

TCP only: C37.118.2's UDP data with TCP commands is not implemented.
Threads and sockets, no ROS import.
"""

from __future__ import annotations

import collections
import selectors
import socket
import threading
import time
from dataclasses import dataclass, field

from .counting import add, drain, merge
from .frames import (Command, Config, DataFrameEncoder, FrameError, FrameType, Measurements, check_reporting_rate,
                     decode_command, encode_config, encode_header)
from .stream import FrameReassembler

#: C37.118's customary TCP port.
DEFAULT_PORT = 4712
#: PDCs that went away whose own counters :meth:`PmuServer.counters` still gives (a run's summary names them).
DEPARTED_KEPT = 64
#: Frames a PDC may have queued before its oldest are dropped: 2 s at 50 frames/s.
DEFAULT_QUEUE_FRAMES = 100
DEFAULT_MAX_CLIENTS = 64
#: Kernel send buffer per PDC (Linux doubles it for its bookkeeping): fixed, so that the kernel's share of a
#: stalled PDC's backlog is bounded too (autotuning would let it grow to megabytes).
SEND_BUFFER_BYTES = 256 * 1024
#: A command frame is 18 bytes; an extended one carries the user's data: this much is accepted.
MAX_COMMAND_BYTES = 1024
#: Frames the plant may hand off before the I/O thread takes them; more are dropped (and counted).
HANDOFF_FRAMES = 1000
#: Frames handed to one ``sendmsg`` call.
SEND_BATCH = 64
_RECV_BYTES = 4096
_SELECT_TIMEOUT_S = 0.5
_COMMAND_NAMES = {Command.DATA_OFF: "data_off", Command.DATA_ON: "data_on", Command.SEND_HEADER: "send_header",
                  Command.SEND_CFG1: "send_cfg1", Command.SEND_CFG2: "send_cfg2", Command.SEND_CFG3: "send_cfg3",
                  Command.EXTENDED: "extended"}
_REPLIES = {Command.SEND_CFG1: FrameType.CFG1, Command.SEND_CFG2: FrameType.CFG2, Command.SEND_CFG3: FrameType.CFG3}


@dataclass
class _Pdc:
    """One connected PDC: its socket, command reader, send queue and counters."""

    sock: socket.socket
    address: str
    reader: FrameReassembler
    data_on: bool = False
    queue: collections.deque = field(default_factory=collections.deque)
    sent_of_head: int = 0
    frames_sent: int = 0
    frames_dropped: int = 0
    bytes_sent: int = 0
    redundant: int = 0
    commands: dict = field(default_factory=dict)
    refused_commands: dict = field(default_factory=dict)

    @property
    def rejected(self) -> dict:
        counts = dict(self.reader.rejected)
        merge(counts, self.refused_commands)
        return counts

    def counters(self) -> dict:
        return {"address": self.address, "data_on": self.data_on, "queued": len(self.queue),
                "frames_sent": self.frames_sent, "frames_dropped": self.frames_dropped, "bytes_sent": self.bytes_sent,
                "commands": dict(self.commands), "rejected": self.rejected, "redundant": self.redundant}


def _address_text(address) -> str:
    host, port = address[0], address[1]
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


class PmuServer:
    """Serves ``config``'s stream over TCP; :meth:`offer` samples from the plant's thread.

    ``header_text`` is the header frame's text (what the stream carries, in
    words). ``config.data_rate`` must be a reporting rate C37.118 allows at
    the stations' nominal frequency (ValueError otherwise).
    """

    def __init__(self, config: Config, header_text: str, *, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 queue_frames: int = DEFAULT_QUEUE_FRAMES, max_clients: int = DEFAULT_MAX_CLIENTS,
                 clock_ns=time.time_ns):
        for station in config.stations:
            check_reporting_rate(config.data_rate, station.nominal_hz)
        if queue_frames < 1 or max_clients < 1:
            raise ValueError("the send queue and the client limit must be at least 1")
        self.config = config
        self.header_text = header_text
        self._host, self._port = host, port
        self._queue_frames, self._max_clients = queue_frames, max_clients
        self._clock_ns = clock_ns
        self._encoder = DataFrameEncoder(config)
        self._handoff: collections.deque = collections.deque()
        self._wake_pending = False
        self._streaming = 0
        self._pdcs: dict[int, _Pdc] = {}
        self._lock = threading.Lock()
        self._events: collections.deque = collections.deque(maxlen=256)
        self._departed: collections.deque = collections.deque(maxlen=DEPARTED_KEPT)
        self._totals = {"connections": 0, "disconnected": 0, "refused": 0, "frames_sent": 0, "frames_dropped": 0,
                        "bytes_sent": 0, "redundant": 0}
        self._commands: dict = {}
        self._rejected: dict = {}
        self.offered = 0
        self.handoff_dropped = 0
        self._thread = None
        self._stopping = False
        self._listener = None
        self.address = None

    # --- the plant's side -------------------------------------------------------------------------

    def offer(self, instant_ns: int, values: Measurements, time_quality: int = 0) -> None:
        """Hand the sample taken at ``instant_ns`` (ns since 1970 UTC) to every PDC with data on; never blocks."""
        self.offered += 1
        if not self._streaming:
            return
        if len(self._handoff) >= HANDOFF_FRAMES:
            self.handoff_dropped += 1
            return
        self._handoff.append(self._encoder.encode(instant_ns, values, time_quality))
        if not self._wake_pending:
            self._wake_pending = True
            try:
                self._wake_send.send(b"\0")
            except BlockingIOError:
                pass

    # --- life cycle -------------------------------------------------------------------------------

    def start(self) -> tuple[str, int]:
        """Bind, listen and start the I/O thread; the (host, port) it listens on."""
        family = socket.AF_INET6 if ":" in self._host else socket.AF_INET
        self._listener = socket.create_server((self._host, self._port), family=family, backlog=16)
        self._listener.setblocking(False)
        self.address = self._listener.getsockname()[:2]
        self._wake_receive, self._wake_send = socket.socketpair()
        for end in (self._wake_receive, self._wake_send):
            end.setblocking(False)
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._listener, selectors.EVENT_READ, "listener")
        self._selector.register(self._wake_receive, selectors.EVENT_READ, "wake")
        self._thread = threading.Thread(target=self._run, name="c37118-pmu-server", daemon=True)
        self._thread.start()
        return self.address

    def stop(self) -> None:
        """Close every connection and the listener; join the I/O thread. Idempotent."""
        if self._thread is None:
            return
        self._stopping = True
        try:
            self._wake_send.send(b"\0")
        except BlockingIOError:
            pass
        self._thread.join()
        self._thread = None
        with self._lock:
            for pdc in list(self._pdcs.values()):
                self._forget(pdc, "the server stopped")
        self._selector.close()
        for sock in (self._listener, self._wake_receive, self._wake_send):
            sock.close()

    def __enter__(self) -> PmuServer:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- what the node reads ----------------------------------------------------------------------

    @property
    def streaming(self) -> int:
        """PDCs with data on now."""
        return self._streaming

    def events(self) -> list[str]:
        """The lines to log since the last call (oldest first; at most the last 256)."""
        return drain(self._events)

    def counters(self) -> dict:
        """Totals (over every PDC ever connected), one dict per connected PDC (``pdcs``) and per PDC that went
        away (``departed``, the last :data:`DEPARTED_KEPT`, oldest first)."""
        with self._lock:
            pdcs = [pdc.counters() for pdc in self._pdcs.values()]
            departed = list(self._departed)
            totals = dict(self._totals)
            commands, rejected = dict(self._commands), dict(self._rejected)
        for pdc in pdcs:
            for key in ("frames_sent", "frames_dropped", "bytes_sent", "redundant"):
                totals[key] += pdc[key]
            merge(commands, pdc["commands"])
            merge(rejected, pdc["rejected"])
        return {"connected": len(pdcs), **totals, "offered": self.offered, "handoff_dropped": self.handoff_dropped,
                "commands": commands, "rejected": rejected, "pdcs": pdcs, "departed": departed}

    # --- the I/O thread ---------------------------------------------------------------------------

    def _run(self) -> None:
        while not self._stopping:
            for key, mask in self._selector.select(_SELECT_TIMEOUT_S):
                with self._lock:
                    if key.data == "listener":
                        self._accept()
                    elif key.data == "wake":
                        self._take_handoff()
                    elif key.fd in self._pdcs:
                        pdc = self._pdcs[key.fd]
                        if mask & selectors.EVENT_READ:
                            self._receive(pdc)
                        if mask & selectors.EVENT_WRITE and key.fd in self._pdcs:
                            self._flush(pdc)

    def _accept(self) -> None:
        while True:
            try:
                sock, address = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            if len(self._pdcs) >= self._max_clients:
                self._totals["refused"] += 1
                self._events.append(f"PDC {_address_text(address)} refused: {self._max_clients} PDCs already "
                                    f"connected")
                sock.close()
                continue
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
            pdc = _Pdc(sock, _address_text(address), FrameReassembler(MAX_COMMAND_BYTES))
            self._pdcs[sock.fileno()] = pdc
            self._selector.register(sock, selectors.EVENT_READ)
            self._totals["connections"] += 1
            self._events.append(f"PDC {pdc.address} connected")

    def _take_handoff(self) -> None:
        try:
            while self._wake_receive.recv(_RECV_BYTES):
                pass
        except BlockingIOError:
            pass
        self._wake_pending = False
        streaming = [pdc for pdc in self._pdcs.values() if pdc.data_on]
        while self._handoff:
            frame = self._handoff.popleft()
            for pdc in streaming:
                self._enqueue(pdc, frame)
        for pdc in streaming:
            if pdc.queue:
                self._flush(pdc)

    def _enqueue(self, pdc: _Pdc, frame: bytes) -> None:
        if len(pdc.queue) >= self._queue_frames:
            # Drop the oldest frame not yet begun: a frame half sent must be finished or the stream breaks.
            if pdc.sent_of_head and len(pdc.queue) > 1:
                del pdc.queue[1]
            elif not pdc.sent_of_head:
                pdc.queue.popleft()
            else:
                pdc.frames_dropped += 1
                return
            pdc.frames_dropped += 1
        was_idle = not pdc.queue
        pdc.queue.append(frame)
        if was_idle:
            self._selector.modify(pdc.sock, selectors.EVENT_READ | selectors.EVENT_WRITE)

    def _flush(self, pdc: _Pdc) -> None:
        while pdc.queue:
            batch = [memoryview(pdc.queue[0])[pdc.sent_of_head:]]
            batch += [pdc.queue[k] for k in range(1, min(len(pdc.queue), SEND_BATCH))]
            try:
                sent = pdc.sock.sendmsg(batch)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as error:
                self._forget(pdc, f"send failed: {error.strerror or error}")
                return
            pdc.bytes_sent += sent
            sent += pdc.sent_of_head
            while pdc.queue and sent >= len(pdc.queue[0]):
                sent -= len(pdc.queue.popleft())
                pdc.frames_sent += 1
            pdc.sent_of_head = sent
        self._selector.modify(pdc.sock, selectors.EVENT_READ)

    def _receive(self, pdc: _Pdc) -> None:
        try:
            data = pdc.sock.recv(_RECV_BYTES)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as error:
            self._forget(pdc, f"connection lost: {error.strerror or error}")
            return
        if not data:
            pdc.reader.finish()
            self._forget(pdc, "closed by the PDC")
            return
        for frame in pdc.reader.feed(data):
            self._command(pdc, frame)

    def _command(self, pdc: _Pdc, frame: bytes) -> None:
        try:
            command = decode_command(frame, self.config.idcode)
        except FrameError as error:
            add(pdc.refused_commands, error.reason)
            return
        name = _COMMAND_NAMES.get(command.command)
        if name is None:
            add(pdc.refused_commands, "unknown_command")
            return
        add(pdc.commands, name)
        if command.command in (Command.DATA_ON, Command.DATA_OFF):
            on = command.command == Command.DATA_ON
            if pdc.data_on == on:
                pdc.redundant += 1
                return
            pdc.data_on = on
            self._streaming += 1 if on else -1
            self._events.append(f"PDC {pdc.address} turned data {'on' if on else 'off'}")
        elif command.command == Command.SEND_HEADER:
            self._enqueue(pdc, encode_header(self.config.idcode, self.header_text, self._clock_ns(),
                                             time_base=self.config.time_base))
            self._flush(pdc)
        elif command.command in _REPLIES:
            self._enqueue(pdc, encode_config(self.config, _REPLIES[command.command], self._clock_ns()))
            self._flush(pdc)

    def _forget(self, pdc: _Pdc, why: str) -> None:
        fd = pdc.sock.fileno()
        if self._pdcs.get(fd) is not pdc:
            return
        del self._pdcs[fd]
        self._selector.unregister(pdc.sock)
        pdc.sock.close()
        if pdc.data_on:
            self._streaming -= 1
        self._totals["disconnected"] += 1
        # Frames still queued for a PDC that went away were never delivered: they count as dropped.
        record = {**pdc.counters(), "data_on": False, "queued": 0,
                  "frames_dropped": pdc.frames_dropped + len(pdc.queue), "why": why}
        for key in ("frames_sent", "frames_dropped", "bytes_sent", "redundant"):
            self._totals[key] += record[key]
        merge(self._commands, pdc.commands)
        merge(self._rejected, pdc.rejected)
        self._departed.append(record)
        self._events.append(f"PDC {pdc.address} went away ({why}): sent {record['frames_sent']} frames, "
                            f"dropped {record['frames_dropped']}")
