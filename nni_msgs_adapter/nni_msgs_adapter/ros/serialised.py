"""Per-sample messages published as bytes: rclpy's serialisation of one template, the changing values patched in.

The loop's nodes publish the same message with new values at every sample (the
plant's measurement, /clock and state, the controller's command and state).
``Publisher.publish(msg)`` converts the Python message to C and lets Fast DDS
serialise it; ``Publisher.publish(bytes)`` takes the CDR bytes as they are (as
``ros2 bag play`` publishes). Measured here with one matched reader in another
process: publish p50 61-70 us for the JointState, 42-49 us for its bytes; at two
such publishes on the lockstep loop's critical path per cycle.

No byte is written by hand. At construction the message builder (one of
:mod:`.contract`'s) is serialised by rclpy with sentinel values, and the offset of
each sentinel's bytes in the output is found: the stamp's (sec int32, nanosec
uint32) and each value's (float64). :meth:`Serialiser.serialise` writes new values
at those offsets. That is right for a builder whose values change only numeric
fields of a fixed layout, as the contract's per-sample messages do
(tests/test_serialised.py checks each against rclpy's bytes for edge values).
Construction checks the result against rclpy's own serialisation of the same
message with other values (the sentinels are negative, the check's first value
positive); if they differ (a big-endian encoding, a layout that changes with
them) or a sentinel is not found exactly once, every call serialises the built
message with rclpy instead: slower, never wrong.
"""

from __future__ import annotations

import struct

from rclpy.serialization import serialize_message

_STAMP = struct.Struct("<iI")
_VALUE = struct.Struct("<d")
#: Sentinels: a stamp and values whose bytes do not occur elsewhere in a small message.
_SENTINEL_STAMP_NS = 0x3A7B5C1D * 1_000_000_000 + 0x13579BDF
_SENTINEL_VALUES = tuple(-1.2345678901234567e-100 * (index + 3) for index in range(16))
#: The check's stamp and values (other than the sentinels, a negative value and a NaN among them).
_CHECK_STAMP_NS = 1_764_597_600 * 1_000_000_000 + 123_456_789
_CHECK_VALUES = (0.25, -3.5, float("nan"), 1e300, -0.0, 7.0, 1.0, 0.0, 2.5, -1.0, 3.0, 4.0, 5.0, 6.0, 8.0, 9.0)


class Serialiser:
    """``serialise(stamp_ns, *values)``: the bytes of ``build(stamp_ns, *values)``, as rclpy serialises them.

    ``build`` takes an integer stamp (ns) and ``count`` floats (a bool is taken as
    1.0 / 0.0, as the builders store it); ``patched`` says whether calls patch the
    template (True) or serialise the built message (False, see the module's text).
    """

    def __init__(self, build, count: int):
        if count > len(_SENTINEL_VALUES):
            raise ValueError(f"at most {len(_SENTINEL_VALUES)} values, got {count}")
        self._build, self._count = build, count
        template = serialize_message(build(_SENTINEL_STAMP_NS, *_SENTINEL_VALUES[:count]))
        self._buffer = bytearray(template)
        sec, nanosec = divmod(_SENTINEL_STAMP_NS, 1_000_000_000)
        offsets = [_only_offset(template, _STAMP.pack(sec, nanosec))]
        offsets += [_only_offset(template, _VALUE.pack(value)) for value in _SENTINEL_VALUES[:count]]
        self.patched = None not in offsets
        if self.patched:
            self._stamp_offset, self._value_offsets = offsets[0], tuple(offsets[1:])
            check = (_CHECK_STAMP_NS, *_CHECK_VALUES[:count])
            self.patched = self.serialise(*check) == serialize_message(build(*check))

    def serialise(self, stamp_ns: int, *values) -> bytes:
        """The message's CDR bytes, for ``Publisher.publish``."""
        if len(values) != self._count:
            raise TypeError(f"{self._count} values expected, got {len(values)}")
        if not self.patched:
            return serialize_message(self._build(stamp_ns, *values))
        buffer = self._buffer
        _STAMP.pack_into(buffer, self._stamp_offset, *divmod(stamp_ns, 1_000_000_000))
        for offset, value in zip(self._value_offsets, values):
            _VALUE.pack_into(buffer, offset, value)
        return bytes(buffer)


def _only_offset(data: bytes, pattern: bytes) -> int | None:
    """Where ``pattern`` occurs in ``data`` if it occurs exactly once, else None."""
    first = data.find(pattern)
    return first if first >= 0 and data.find(pattern, first + 1) < 0 else None
