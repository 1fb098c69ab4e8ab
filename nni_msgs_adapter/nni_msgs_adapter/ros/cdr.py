"""The CDR bytes of the loop's per-sample messages, for ``Publisher.publish(bytes)``.

The loop's nodes publish one message layout per topic at every sample with a new
stamp and new values: the plant its measurement, /clock and true state, the
controller its command and state. ``Publisher.publish(msg)`` converts the Python
message to C and has Fast DDS serialise it; ``publish(bytes)`` hands the bytes to
the writer as they are (as ``ros2 bag play`` does). Measured with one matched
reader in another process: p50 61-70 us for the JointState, 42-49 us for its bytes,
two such publishes on the lockstep loop's critical path a cycle.

The bytes are those rmw_fastrtps writes for the message itself (XCDR1,
little-endian, padding zeroed): a reader, the logger and a recording cannot tell
them apart (tests/test_cdr.py checks each layout against what a normal publish
delivers). rclpy's ``serialize_message`` is no source for them: it returns
rmw_serialize's size estimate, 8 bytes longer than the message for a command,
the tail and the padding uninitialised memory (measured), so that the last
attempt at this, built on it, recorded 76-byte commands whose last 8 bytes
changed from run to run.

XCDR1 (OMG DDS-XTypes 1.3, 7.4.1, "plain CDR"): after the 4-byte encapsulation
header, each primitive is aligned to its size (a float64 to 8), counted from the
start of the data; a string is its uint32 length with the NUL, its bytes, a NUL;
a sequence is its uint32 count, then its elements. Pure Python: no ROS import.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

#: CDR_LE: plain CDR, little-endian (the encapsulation identifier and its two option bytes).
ENCAPSULATION_LE = b"\x00\x01\x00\x00"
_UINT32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")


class _Writer:
    """A growing CDR_LE buffer that aligns each primitive from the start of the data."""

    def __init__(self):
        self.out = bytearray(ENCAPSULATION_LE)

    def align(self, size: int) -> int:
        self.out.extend(bytes(-(len(self.out) - len(ENCAPSULATION_LE)) % size))
        return len(self.out)

    def uint32(self, value: int) -> None:
        self.align(4)
        self.out.extend(_UINT32.pack(value))

    def string(self, text: str) -> None:
        data = text.encode()
        self.uint32(len(data) + 1)
        self.out.extend(data + b"\x00")

    def reserve(self, size: int, alignment: int) -> int:
        """Zeros for a value to be packed later; returns their offset."""
        offset = self.align(alignment)
        self.out.extend(bytes(size))
        return offset


class StampedBytes:
    """The bytes of one layout with a stamp (``builtin_interfaces/Time``) and float64 values to fill in.

    :meth:`pack` writes ``stamp_ns`` as (sec int32, nanosec uint32, as
    :func:`nni_msgs_adapter.ros.contract.time_from_ns` splits it) and the values,
    in order, and returns the message's bytes. A layout with a text slot
    (``text``: its offset and length, a fixed-length tail of a string) takes
    the slot's bytes as its last value.

    Every byte of a layout is either fixed (the encapsulation, the frame_id, the
    names, the counts, the padding) or a slot (the stamp, the values, the text).
    One struct reads and writes all the slots at once, skipping the fixed bytes
    (pad bytes ``x``, which it writes as zeros), and the fixed bytes are the
    template's under a mask: packing ORs them in, reading compares them, each as
    one integer operation. A measurement packs in 1.3 us and reads back in 1.3
    (timeit), where writing each slot into the template took 3.1 and comparing
    each fixed stretch 2.4: two of each per generator and sample on the loop's
    path (the measurement at the plant and its controller, the command back).
    """

    def __init__(self, writer: _Writer, stamp_offset: int, groups: list[tuple[int, struct.Struct]],
                 text: tuple[int, int] | None = None):
        template = bytes(writer.out)
        self.size = len(template)
        self._text_length = None if text is None else text[1]
        self.count = sum(group.size // 8 for _, group in groups) + (text is not None)
        if text is not None and any(offset < text[0] for offset, _ in groups):
            raise ValueError("a text slot comes before the values (it is in the header)")
        slots = sorted([(stamp_offset, _STAMP.format[1:])]
                       + [(offset, group.format[1:]) for offset, group in groups]
                       + ([(text[0], f"{text[1]}s")] if text else []))
        fields, mask, at = ["<"], bytearray(b"\xff" * self.size), 0
        for offset, form in slots:
            width = struct.calcsize("<" + form)
            fields += [f"{offset - at}x"] if offset > at else []
            fields.append(form)
            mask[offset:offset + width] = bytes(width)
            at = offset + width
        fields += [f"{self.size - at}x"] if self.size > at else []
        self._slots = struct.Struct("".join(fields))
        self._mask = int.from_bytes(mask, "little")
        self._fixed = int.from_bytes(template, "little") & self._mask

    def pack(self, stamp_ns: int, *values) -> bytes:
        if len(values) != self.count:
            raise TypeError(f"{self.count} values expected, got {len(values)}")
        if self._text_length is None:
            slots = self._slots.pack(*divmod(stamp_ns, 1_000_000_000), *values)
        elif len(values[-1]) != self._text_length:
            raise ValueError(f"the text slot takes {self._text_length} bytes, got {len(values[-1])}")
        else:  # the text (header.frame_id) comes before the values on the wire
            slots = self._slots.pack(*divmod(stamp_ns, 1_000_000_000), values[-1], *values[:-1])
        return (int.from_bytes(slots, "little") | self._fixed).to_bytes(self.size, "little")

    def unpack(self, data: bytes) -> tuple[int, tuple] | None:
        """``(stamp_ns, values)`` of bytes of this layout, as :meth:`pack` writes them; None for any other bytes.

        Other bytes may still be a valid message (another encoding, frame_id, size or
        padding): the caller deserialises those (:func:`nni_msgs_adapter.ros.contract.command_from_bytes`).
        """
        if len(data) != self.size or int.from_bytes(data, "little") & self._mask != self._fixed:
            return None
        sec, nanosec, *values = self._slots.unpack(data)
        if self._text_length is not None:
            values.append(values.pop(0))
        return sec * 1_000_000_000 + nanosec, tuple(values)


def joint_state(frame_id: str, names: Sequence[str], counts: tuple[int, int, int],
                frame_tail: int = 0) -> StampedBytes:
    """sensor_msgs/JointState with ``frame_id``, ``names`` and (position, velocity, effort) of ``counts`` values.

    ``frame_tail``: the frame_id goes on for this many more bytes (ASCII, no NUL), a text slot that
    :meth:`StampedBytes.pack` fills in last.
    """
    writer = _Writer()
    stamp_offset = writer.reserve(_STAMP.size, 4)  # std_msgs/Header: stamp (sec, nanosec), frame_id
    writer.string(frame_id + "0" * frame_tail)
    text = (len(writer.out) - 1 - frame_tail, frame_tail) if frame_tail else None  # before the string's NUL
    writer.uint32(len(names))
    for name in names:
        writer.string(name)
    groups = []
    for count in counts:
        writer.uint32(count)
        if count:
            group = struct.Struct(f"<{count}d")
            groups.append((writer.reserve(group.size, 8), group))
    return StampedBytes(writer, stamp_offset, groups, text)


def clock() -> StampedBytes:
    """rosgraph_msgs/Clock: one ``builtin_interfaces/Time``."""
    writer = _Writer()
    return StampedBytes(writer, writer.reserve(_STAMP.size, 4), [])
