"""The PDC side of C37.118.2 over TCP: connect to a PMU or PDC, take its configuration, then its samples.

:class:`PdcSession` is the protocol with no socket (testable byte by byte):
its :meth:`~PdcSession.opening` is the CFG-2 request; :meth:`~PdcSession.feed`
takes received bytes and gives the station samples they complete and the
commands to send back ("data on" once a configuration has been read; CFG-2
again when a station flags a configuration change). It rejects, and counts
under ``rejected`` by reason:

* every bad frame of the byte stream (:mod:`.stream`: ``bad_sync``,
  ``bad_crc``, ``truncated``, ``oversized``, ``bad_framesize``, ...), and
  every frame :mod:`.frames` refuses (``wrong_idcode``: a frame of another
  stream; ``bad_framesize``: a data frame whose size is not its
  configuration's; ``bad_fracsec``, ``bad_body``, ``wrong_type`` for a
  command frame, ...);
* ``no_config``: a data frame before any configuration;
* ``config_changed``: a configuration unlike the first one the session took (the session pins it: stations,
  channels, FNOM, CFGCNT, rate; a PMU reconfigured on purpose needs a new session), and ``config_mismatch``: one
  that ``accept_config(config)`` refuses (its text says why: the node's stations and channels are not there).
  Either ends the connection (:attr:`PdcSession.refused` says why; :class:`PdcClient` reconnects after its
  wait), and no data frame is read with it;
* ``time_backwards`` and ``duplicate``: a data frame stamped before, or at,
  the last one accepted on this connection;
* ``stale``: a data frame older than ``max_age_ns`` by ``clock_ns()`` when it
  is read (no age bound when ``max_age_ns`` is None: a lockstep run's clock
  is not the wall clock);
* ``invalid_data``, per station: STAT bits 15-14 not 00 (the PMU says the
  values are not to be used); the other stations of the frame pass.

:class:`PdcClient` runs a session on a socket in its own thread and hands
each frame's samples to a callback. Reconnect policy: after a failed connect
or a lost connection it waits ``retry_initial_s`` (0.5 s), doubling each
failure up to ``retry_max_s`` (5 s), back to the initial wait once a
connection delivered samples; a connection silent for ``silence_timeout_s``
(10 s) is dropped and remade. Each connection starts afresh (CFG-2 request,
then data on), and "time going backwards" is judged within a connection.
Threads and sockets, no ROS import.
"""

from __future__ import annotations

import collections
import selectors
import socket
import threading
import time
from dataclasses import dataclass

from .counting import add, drain
from .frames import (CONFIG_TYPES, MAX_FRAME_BYTES, Command, Config, DataFrameDecoder, FrameError, FrameType, Stat,
                     StationReading, decode_config, decode_header, encode_command, read_head)
from .stream import FrameReassembler

RETRY_INITIAL_S = 0.5
RETRY_MAX_S = 5.0
SILENCE_TIMEOUT_S = 10.0
CONNECT_TIMEOUT_S = 2.0
_RECV_BYTES = 65536
_POLL_S = 0.2


@dataclass(frozen=True)
class StationSample:
    """One station's measurement from one data frame, stamped from SOC/FRACSEC (ns since 1970 UTC).

    ``station`` is its index in the configuration (data frame order);
    ``reading`` its values in physical units (angles in [-pi, pi] as C37.118
    sends them).
    """

    station: int
    name: str
    idcode: int
    instant_ns: int
    reading: StationReading


class PdcSession:
    """The client protocol of one stream (IDCODE ``idcode``), connection after connection, without sockets."""

    def __init__(self, idcode: int, *, max_age_ns: int | None = None, clock_ns=time.time_ns,
                 max_frame_bytes: int = MAX_FRAME_BYTES, accept_config=None):
        self.idcode = idcode
        self._accept_config = accept_config
        #: Why the last configuration was refused (its connection is to end), None while none was.
        self.refused: str | None = None
        self.max_age_ns = max_age_ns
        self._clock_ns = clock_ns
        self.reader = FrameReassembler(max_frame_bytes)
        self.config: Config | None = None
        self.header_text: str | None = None
        self.frames: dict[str, int] = {}
        self.samples = 0
        self._rejected: dict[str, int] = {}
        self._decoder: DataFrameDecoder | None = None
        self._data_on = False
        self._config_requested = False
        self._last_instant_ns: int | None = None

    @property
    def rejected(self) -> dict[str, int]:
        counts = dict(self.reader.rejected)
        for reason, n in self._rejected.items():
            add(counts, reason, n)
        return counts

    def _command(self, command: Command) -> bytes:
        return encode_command(self.idcode, command, self._clock_ns())

    def opening(self) -> bytes:
        """What to send on a new connection: the CFG-2 request (the connection's state starts afresh)."""
        self.reader.finish()
        self._data_on, self._config_requested, self._last_instant_ns = False, True, None
        self.refused = None
        return self._command(Command.SEND_CFG2)

    def closed(self) -> None:
        """The connection ended: a frame it left incomplete is counted ``truncated``."""
        self.reader.finish()

    def feed(self, data) -> tuple[list[StationSample], list[bytes]]:
        """The samples ``data`` completes and the commands to send back."""
        samples, replies = [], []
        for frame in self.reader.feed(data):
            try:
                self._frame(frame, samples, replies)
            except FrameError as error:
                add(self._rejected, error.reason)
        self.samples += len(samples)
        return samples, replies

    def _frame(self, frame: bytes, samples: list, replies: list) -> None:
        head = read_head(frame, self.reader.max_frame_bytes)
        if head.idcode != self.idcode:
            raise FrameError("wrong_idcode", f"IDCODE {head.idcode}, expected {self.idcode}")
        if head.frame_type in CONFIG_TYPES:
            config = decode_config(frame, self.idcode).config
            add(self.frames, head.frame_type.name.lower())
            if self._refuses(config):
                return
            self.config = config
            self._decoder = DataFrameDecoder(self.config)
            self._config_requested = False
            if not self._data_on:
                self._data_on = True
                replies.append(self._command(Command.DATA_ON))
        elif head.frame_type == FrameType.HEADER:
            self.header_text = decode_header(frame, self.idcode).text
            add(self.frames, "header")
        elif head.frame_type == FrameType.DATA:
            self._data(frame, samples, replies)
        else:
            raise FrameError("wrong_type", f"a {head.frame_type.name} frame from the PMU")

    def _refuses(self, config: Config) -> bool:
        """Whether this session does not take ``config`` (counted, and :attr:`refused` set, if so)."""
        if self.config is not None and config != self.config:
            reason, self.refused = "config_changed", ("a configuration unlike the one this client took first (a PMU "
                                                      "reconfigured on purpose needs the client restarted)")
        else:
            reason, self.refused = "config_mismatch", self._accept_config and self._accept_config(config)
        if self.refused is not None:
            add(self._rejected, reason)
        return self.refused is not None

    def _data(self, frame: bytes, samples: list, replies: list) -> None:
        if self.refused is not None:
            return  # the connection is ending: nothing more of it is read
        if self._decoder is None:
            add(self._rejected, "no_config")
            return
        data = self._decoder.decode(frame)
        add(self.frames, "data")
        if self._last_instant_ns is not None and data.instant_ns <= self._last_instant_ns:
            add(self._rejected, "duplicate" if data.instant_ns == self._last_instant_ns else "time_backwards")
            return
        if self.max_age_ns is not None and self._clock_ns() - data.instant_ns > self.max_age_ns:
            add(self._rejected, "stale")
            return
        self._last_instant_ns = data.instant_ns
        for k, (station, reading) in enumerate(zip(self.config.stations, data.stations)):
            stat = Stat.from_word(reading.stat)
            if stat.config_changed and not self._config_requested:
                self._config_requested = True
                replies.append(self._command(Command.SEND_CFG2))
            if not stat.data_valid:
                add(self._rejected, "invalid_data")
                continue
            samples.append(StationSample(k, station.name, station.idcode, data.instant_ns, reading))

    def counters(self) -> dict:
        return {"samples": self.samples, "frames": dict(self.frames), "rejected": self.rejected}


class PdcClient:
    """Keeps a connection to the PMU at ``host:port`` (stream ``idcode``); ``on_samples(list)`` gets each frame's
    samples, from the client's thread."""

    def __init__(self, host: str, port: int, idcode: int, on_samples, *, max_age_ns: int | None = None,
                 accept_config=None, clock_ns=time.time_ns, retry_initial_s: float = RETRY_INITIAL_S,
                 retry_max_s: float = RETRY_MAX_S, silence_timeout_s: float = SILENCE_TIMEOUT_S, connect_timeout_s: float = CONNECT_TIMEOUT_S):
        if not 0 < retry_initial_s <= retry_max_s:
            raise ValueError("the reconnect waits must satisfy 0 < initial <= max")
        self.host, self.port = host, port
        self.session = PdcSession(idcode, max_age_ns=max_age_ns, clock_ns=clock_ns, accept_config=accept_config)
        self._on_samples = on_samples
        self._retry_initial_s, self._retry_max_s = retry_initial_s, retry_max_s
        self._silence_timeout_s, self._connect_timeout_s = silence_timeout_s, connect_timeout_s
        self._events: collections.deque = collections.deque(maxlen=256)
        self._stop = threading.Event()
        self._thread = None
        self.connections = 0
        self.connect_failures = 0
        self.connected = False

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="c37118-pdc-client", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None

    def events(self) -> list[str]:
        """The lines to log since the last call (oldest first; at most the last 256)."""
        return drain(self._events)

    def counters(self) -> dict:
        return {"connected": self.connected, "connections": self.connections,
                "connect_failures": self.connect_failures, **self.session.counters()}

    def _run(self) -> None:
        wait_s = self._retry_initial_s
        where = f"{self.host}:{self.port}"
        while not self._stop.is_set():
            try:
                sock = socket.create_connection((self.host, self.port), timeout=self._connect_timeout_s)
            except OSError as error:
                self.connect_failures += 1
                self._events.append(f"PMU {where} unreachable ({error.strerror or error}); retrying in {wait_s:g} s")
            else:
                self.connections += 1
                self.connected = True
                self._events.append(f"connected to PMU {where}")
                samples_before = self.session.samples
                why = self._serve(sock)
                self.connected = False
                self.session.closed()
                if self.session.samples > samples_before:
                    wait_s = self._retry_initial_s
                if self._stop.is_set():
                    self._events.append(f"disconnected from PMU {where} ({why})")
                    return
                self._events.append(f"PMU {where} went away ({why}); reconnecting in {wait_s:g} s")
            if self._stop.wait(wait_s):
                return
            wait_s = min(2 * wait_s, self._retry_max_s)

    def _serve(self, sock: socket.socket) -> str:
        with sock, selectors.DefaultSelector() as selector:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            selector.register(sock, selectors.EVENT_READ)
            try:
                sock.sendall(self.session.opening())
                heard_at = time.monotonic()
                while not self._stop.is_set():
                    if not selector.select(_POLL_S):
                        if time.monotonic() - heard_at > self._silence_timeout_s:
                            return f"silent for {self._silence_timeout_s:g} s"
                        continue
                    data = sock.recv(_RECV_BYTES)
                    if not data:
                        return "closed by the PMU"
                    heard_at = time.monotonic()
                    samples, replies = self.session.feed(data)
                    if samples:
                        self._on_samples(samples)
                    if self.session.refused is not None:
                        return f"its configuration is refused: {self.session.refused}"
                    for reply in replies:
                        sock.sendall(reply)
            except OSError as error:
                return f"connection lost: {error.strerror or error}"
        return "client stopped"
