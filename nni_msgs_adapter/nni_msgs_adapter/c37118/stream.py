"""Whole C37.118 frames out of a TCP byte stream: bad frames counted and skipped, the stream resynchronised.

:class:`FrameReassembler` is fed the bytes ``recv`` returns, in any chunks,
and gives back every whole frame whose SYNC, FRAMESIZE and CHK check. A bad
candidate is counted once under a :class:`~.frames.FrameError` reason and
skipped:

* a first byte that is not SYNC (0xAA): the bytes up to the next 0xAA are
  dropped, one ``bad_sync`` per run of them (``skipped_bytes`` counts bytes);
* a second SYNC byte with bit 7 set, frame type 6 or 7, or a version not 1
  or 2 (``bad_sync``, ``unknown_type``, ``bad_version``), a FRAMESIZE below
  16 (``bad_framesize``) or beyond ``max_frame_bytes`` (``oversized``):
  resume at the next byte;
* a CHK that does not match: ``truncated`` when another frame of the same
  IDCODE starts inside it (its sender cut it short), resuming there;
  ``bad_crc`` otherwise, resuming at the next byte (never past a possible
  frame start: a damaged FRAMESIZE must not swallow the frames after it).

A bad stretch counts once, by its first fault: until the next good frame,
the candidates tried while resynchronising (0xAA bytes inside a damaged
frame, garbage) are not counted again. Memory is bounded: after each
``feed`` at most one incomplete frame, shorter than ``max_frame_bytes``,
stays buffered.
Pure python: no ROS import.
"""

from __future__ import annotations

from .frames import (CHK_BYTES, MAX_FRAME_BYTES, MIN_FRAME_BYTES, READABLE_VERSIONS, SYNC_BYTE, FrameType,
                     crc_ccitt)

_HEAD_PROBE_BYTES = 6  # SYNC, FRAMESIZE, IDCODE


def _second_byte_fault(second: int) -> str | None:
    if second & 0x80:
        return "bad_sync"
    if second >> 4 > FrameType.CFG3:
        return "unknown_type"
    if second & 0x0F not in READABLE_VERSIONS:
        return "bad_version"
    return None


class FrameReassembler:
    """Feed bytes, get whole frames (bytes, CHK checked); ``rejected`` counts bad candidates by reason."""

    def __init__(self, max_frame_bytes: int = MAX_FRAME_BYTES):
        if not MIN_FRAME_BYTES <= max_frame_bytes <= MAX_FRAME_BYTES:
            raise ValueError(f"the frame bound must be within [{MIN_FRAME_BYTES}, {MAX_FRAME_BYTES}] bytes, got "
                             f"{max_frame_bytes!r}")
        self.max_frame_bytes = max_frame_bytes
        self.rejected: dict[str, int] = {}
        self.frames = 0
        self.skipped_bytes = 0
        self._buffer = bytearray()
        self._resyncing = False

    @property
    def buffered_bytes(self) -> int:
        return len(self._buffer)

    def _reject(self, reason: str) -> None:
        if not self._resyncing:
            self.rejected[reason] = self.rejected.get(reason, 0) + 1
        self._resyncing = True

    def feed(self, data) -> list[bytes]:
        """The frames completed by ``data`` (possibly none), in stream order."""
        buffer = self._buffer
        buffer += data
        frames, at = [], 0
        while at < len(buffer):
            if buffer[at] != SYNC_BYTE:
                sync_at = buffer.find(SYNC_BYTE, at + 1)
                end = len(buffer) if sync_at < 0 else sync_at
                self.skipped_bytes += end - at
                self._reject("bad_sync")
                at = end
                continue
            available = len(buffer) - at
            if available < 4:
                break
            fault = _second_byte_fault(buffer[at + 1])
            size = buffer[at + 2] << 8 | buffer[at + 3]
            if fault is None and size < MIN_FRAME_BYTES:
                fault = "bad_framesize"
            elif fault is None and size > self.max_frame_bytes:
                fault = "oversized"
            if fault is not None:
                self._reject(fault)
                at += 1
                self.skipped_bytes += 1
                continue
            if available < size:
                break
            end = at + size
            if crc_ccitt(memoryview(buffer)[at:end - CHK_BYTES]) == (buffer[end - 2] << 8 | buffer[end - 1]):
                frames.append(bytes(buffer[at:end]))
                self.frames += 1
                self._resyncing = False
                at = end
                continue
            restart = self._next_frame_inside(at, end)
            if restart is not None:
                self._reject("truncated")
            else:
                self._reject("bad_crc")
                restart = at + 1
            self.skipped_bytes += restart - at
            at = restart
        del buffer[:at]
        return frames

    def _next_frame_inside(self, start: int, end: int) -> int | None:
        """Where a frame of the same IDCODE starts within buffer[start + 1:end], if one does."""
        buffer = self._buffer
        idcode = buffer[start + 4:start + 6]
        at = buffer.find(SYNC_BYTE, start + 1, end)
        while 0 <= at and at + _HEAD_PROBE_BYTES <= len(buffer):
            if _second_byte_fault(buffer[at + 1]) is None and buffer[at + 4:at + 6] == idcode:
                return at
            at = buffer.find(SYNC_BYTE, at + 1, end)
        return None

    def finish(self) -> None:
        """The stream ended: a frame left incomplete is counted ``truncated``, garbage ``bad_sync``."""
        if self._buffer:
            self.skipped_bytes += len(self._buffer)
            self._reject("truncated" if self._buffer[0] == SYNC_BYTE else "bad_sync")
            self._buffer.clear()
        self._resyncing = False
