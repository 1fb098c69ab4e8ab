"""Authenticated battery commands: a per-run key, HMAC-SHA256 and a sequence number, without DDS security.

The PyPI Fast DDS has no DDS Security and rclpy gives a subscription callback
no publisher identity, so the plant cannot tell its controller's commands from
a rogue's by the transport. As IEC 62351-6 does for GOOSE and sampled values,
each command carries a message authentication code under a pre-shared key:

* the key: 32 random bytes in a file of the user's own (mode 0600 or
  stricter), named by ``NNI_COMMAND_KEY_FILE`` in the environment of the plant
  and its controller(s); never a parameter, never on the wire, never in a
  recording or a log. ``nni-demo`` and the launch files make a fresh one per
  run (:func:`new_key_file`, in a folder of mode 0700) and remove it after.
* one key per command topic, derived from the file's and the topic's absolute
  name (:func:`topic_key`): a command of ``/gen1/battery/command`` does not
  verify on ``/gen2/battery/command``.
* each command's MAC covers a domain tag, the topic, its sequence number, the
  answered measurement's stamp and the power (:func:`command_mac`); the plant
  admits only a sequence above the last one that verified (:class:`CommandVerifier`),
  so a recorded or captured command replayed later is refused.

A controller's sequence starts at its wall clock in ns (:class:`CommandSigner`),
so a restarted controller keeps counting upwards under the same key.

The seal (``<sequence, 16 hex digits>|<MAC, 64 hex digits>``) travels in the
command's ``header.frame_id`` after ``battery|hmac-sha256|``
(:mod:`nni_msgs_adapter.ros.contract`), fixed in length so that the command
keeps its exact-bytes fast path (:mod:`.cdr`). Pure Python: no ROS import.
"""

from __future__ import annotations

import hmac
import os
import secrets
import shutil
import stat
import struct
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

#: The environment variable naming the key file of the plant and its controllers.
KEY_FILE_ENV = "NNI_COMMAND_KEY_FILE"
#: Length of the key, bytes: 256 bits, HMAC-SHA256's output.
KEY_BYTES = 32
#: The scheme's name on the wire (``header.frame_id``: ``battery|hmac-sha256|<seal>``).
SCHEME = "hmac-sha256"
#: Hex digits of the sequence number and of the MAC in a seal, and the seal's length.
SEQUENCE_DIGITS, MAC_DIGITS = 16, 64
SEAL_LENGTH = SEQUENCE_DIGITS + 1 + MAC_DIGITS
#: Domain tags: a topic key and a command MAC can never be mistaken for one another.
_KEY_TAG = b"nni battery command key\x00"
_MAC_TAG = b"nni battery command v1\x00"
_FIELDS = struct.Struct("<Qqd")  # sequence, stamp (ns), power (pu, the float64 of the wire)
_HEX = frozenset(b"0123456789abcdef")
#: File name of a key in the folder :func:`new_key_file` makes.
_KEY_NAME = "command.key"


class KeyFileError(ValueError):
    """A key file that cannot be used (one line: which file, and why)."""


def read_key(path: str | os.PathLike) -> bytes:
    """The key in ``path``: a regular file of this user's, unreadable to group and others, of exactly 32 bytes."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError as error:
        raise KeyFileError(f"{KEY_FILE_ENV}={path}: cannot open the key file ({error.strerror})") from None
    try:
        status = os.fstat(fd)
        if not stat.S_ISREG(status.st_mode):
            raise KeyFileError(f"{KEY_FILE_ENV}={path} is not a regular file")
        if status.st_uid != os.getuid():
            raise KeyFileError(f"{KEY_FILE_ENV}={path} is not this user's own (owner {status.st_uid})")
        if status.st_mode & 0o077:
            raise KeyFileError(f"{KEY_FILE_ENV}={path} is readable or writable by group or others (mode "
                               f"{stat.S_IMODE(status.st_mode):o}): chmod 600 it")
        key = os.read(fd, KEY_BYTES + 1)
    finally:
        os.close(fd)
    if len(key) != KEY_BYTES:
        raise KeyFileError(f"{KEY_FILE_ENV}={path} is not a key: {KEY_BYTES} random bytes expected, the file has "
                        f"{len(key) if len(key) <= KEY_BYTES else 'more'}")
    return key


def key_from_environment(environ=os.environ) -> bytes | None:
    """The key of ``NNI_COMMAND_KEY_FILE``, None when it is unset or empty; KeyFileError for a file that cannot be used."""
    path = environ.get(KEY_FILE_ENV, "")
    return read_key(path) if path else None


def new_key_file() -> Path:
    """A fresh key (``secrets``, 32 bytes) in a new folder of mode 0700 in the temporary directory; its path."""
    folder = Path(tempfile.mkdtemp(prefix="nni-command-key-"))  # mkdtemp: mode 0700, this user's
    path = folder / _KEY_NAME
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as handle:
        handle.write(secrets.token_bytes(KEY_BYTES))
    return path


def remove_key_file(path: Path) -> None:
    """Remove a key made by :func:`new_key_file`, and its folder."""
    shutil.rmtree(Path(path).parent, ignore_errors=True)


@contextmanager
def run_key():
    """A fresh key file (:func:`new_key_file`) for the block, removed when it ends; yields its path."""
    path = new_key_file()
    try:
        yield path
    finally:
        remove_key_file(path)


def topic_key(key: bytes, topic: str) -> bytes:
    """The key of one command topic (its absolute name, ``/gen1/battery/command``), derived from the run's."""
    return hmac.digest(key, _KEY_TAG + topic.encode(), "sha256")


def command_mac(key: bytes, topic: str, sequence: int, stamp_ns: int, power_pu: float) -> bytes:
    """The MAC (64 lowercase hex digits, ASCII) of one command on ``topic``, under that topic's ``key``."""
    message = _MAC_TAG + topic.encode() + b"\x00" + _FIELDS.pack(sequence, stamp_ns, power_pu)
    return hmac.digest(key, message, "sha256").hex().encode()


class CommandSigner:
    """Seals a controller's commands on ``topic``: sequence numbers from ``first_sequence`` (default: now, in ns)."""

    def __init__(self, key: bytes, topic: str, first_sequence: int | None = None):
        self.topic, self._key = topic, topic_key(key, topic)
        self.sequence = time.time_ns() if first_sequence is None else first_sequence

    def seal(self, stamp_ns: int, power_pu: float) -> bytes:
        """The seal of the next command (``SEAL_LENGTH`` ASCII bytes for the frame_id)."""
        self.sequence += 1
        return b"%016x|" % self.sequence + command_mac(self._key, self.topic, self.sequence, stamp_ns, power_pu)


#: What :meth:`CommandVerifier.check` says of a seal.
AUTHENTIC, UNAUTHENTICATED, REPLAYED = "authentic", "unauthenticated", "replayed"


class CommandVerifier:
    """Checks the seals of the commands on ``topic``: the MAC, and a sequence above the last that verified."""

    def __init__(self, key: bytes, topic: str):
        self.topic, self._key = topic, topic_key(key, topic)
        self.last_sequence = -1

    def check(self, seal: bytes | None, stamp_ns: int, power_pu: float) -> str:
        """AUTHENTIC (and the sequence recorded), UNAUTHENTICATED (no seal, malformed, a MAC that does not
        verify) or REPLAYED (a MAC that verifies on a sequence at or below the last one)."""
        if seal is None or len(seal) != SEAL_LENGTH or seal[SEQUENCE_DIGITS] != ord("|") \
                or not _HEX.issuperset(seal[:SEQUENCE_DIGITS]):
            return UNAUTHENTICATED
        sequence = int(seal[:SEQUENCE_DIGITS], 16)
        expected = command_mac(self._key, self.topic, sequence, stamp_ns, power_pu)
        if not hmac.compare_digest(seal[SEQUENCE_DIGITS + 1:], expected):
            return UNAUTHENTICATED
        if sequence <= self.last_sequence:
            return REPLAYED
        self.last_sequence = sequence
        return AUTHENTIC
