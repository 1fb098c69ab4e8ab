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


#: A run's key folder in the temporary directory: this prefix, the pid of the process that made it, ``-``, random.
KEY_FOLDER_PREFIX = "nni-command-key-"


def new_key_file() -> Path:
    """A fresh key (``secrets``, 32 bytes) in a new folder of mode 0700 in the temporary directory; its path.

    The folder's name carries the maker's pid: the key folders of this user's runs whose maker is gone (a run
    killed with SIGKILL, which removes nothing) are removed first (:func:`remove_stale_key_folders`).
    """
    remove_stale_key_folders()
    folder = Path(tempfile.mkdtemp(prefix=f"{KEY_FOLDER_PREFIX}{os.getpid()}-"))  # mkdtemp: mode 0700, this user's
    path = folder / _KEY_NAME
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as handle:
        handle.write(secrets.token_bytes(KEY_BYTES))
    return path


def remove_stale_key_folders(folder: str | os.PathLike | None = None) -> list[Path]:
    """Remove this user's key folders in ``folder`` (default: the temporary directory) whose maker's pid is not
    running any more, and any of the earlier naming (no pid) older than a day; the folders removed."""
    removed = []
    for entry in Path(folder or tempfile.gettempdir()).glob(KEY_FOLDER_PREFIX + "*"):
        try:
            status = entry.lstat()
        except OSError:
            continue
        if not stat.S_ISDIR(status.st_mode) or status.st_uid != os.getuid():
            continue
        pid = entry.name[len(KEY_FOLDER_PREFIX):].partition("-")[0]
        if pid.isdigit() and int(pid) > 0:
            if _running(int(pid)):
                continue
        elif time.time() - status.st_mtime < 86_400:
            continue
        shutil.rmtree(entry, ignore_errors=True)
        removed.append(entry)
    return removed


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


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


#: What a key seals: its key's domain tag and its MAC's. Every direction has a key of its own, derived from the
#: run's and the topic's name (:func:`topic_key`): a seal made for one kind or one topic verifies on no other.
#: ``command``: a controller's battery command; ``measurement``: a plant's (or the C37.118 client's) ``pmu``;
#: ``state``: ``plant/state`` and ``controller/state`` (what analysis and the recording read); ``status``: the
#: plant's ``run_ended`` on ``/diagnostics``.
KINDS = {
    "command": (_KEY_TAG, _MAC_TAG),
    "measurement": (b"nni measurement key\x00", b"nni measurement v1\x00"),
    "state": (b"nni state key\x00", b"nni state v1\x00"),
    "status": (b"nni status key\x00", b"nni status v1\x00"),
}
#: A measurement's seal starts with the plant's mode, under the MAC: ``L|`` lockstep (its stamps are the simulated
#: clock), ``R|`` realtime (its stamps are wall time); then the seal of :data:`SEAL_LENGTH`.
LOCKSTEP_FLAG, REALTIME_FLAG = b"L|", b"R|"
FLAG_LENGTH = 2
MEASUREMENT_SEAL_LENGTH = FLAG_LENGTH + SEAL_LENGTH
_STRUCTS: dict[int, struct.Struct] = {}


def topic_key(key: bytes, topic: str, kind: str = "command") -> bytes:
    """The key of one topic (its absolute name, ``/gen1/battery/command``) and kind (:data:`KINDS`), derived from the
    run's."""
    return hmac.digest(key, KINDS[kind][0] + topic.encode(), "sha256")


def _fields(sequence: int, stamp_ns: int, values) -> bytes:
    form = _STRUCTS.get(len(values))
    if form is None:
        form = _STRUCTS[len(values)] = struct.Struct(f"<Qq{len(values)}d")
    return form.pack(sequence, stamp_ns, *values)


def seal_mac(key: bytes, kind: str, topic: str, sequence: int, stamp_ns: int, values, flag: bytes = b"") -> bytes:
    """The MAC (64 lowercase hex digits, ASCII) of one message on ``topic`` under that topic's ``key``: over the
    kind's tag, the topic, the flag, the sequence, the stamp and the float64 ``values`` (a JointState's positions,
    velocities and efforts, in that order)."""
    message = KINDS[kind][1] + topic.encode() + b"\x00" + flag + _fields(sequence, stamp_ns, values)
    return hmac.digest(key, message, "sha256").hex().encode()


def command_mac(key: bytes, topic: str, sequence: int, stamp_ns: int, power_pu: float) -> bytes:
    """The MAC of one command on ``topic``, under that topic's ``key`` (:func:`seal_mac` of kind ``command``)."""
    return seal_mac(key, "command", topic, sequence, stamp_ns, (power_pu,))


class Signer:
    """Seals the messages of one ``kind`` on ``topic``: sequence numbers from ``first_sequence`` (default: now, in
    ns, so that a restarted sender counts on upwards under the same key)."""

    def __init__(self, key: bytes, topic: str, kind: str = "command", first_sequence: int | None = None):
        self.topic, self.kind, self._key = topic, kind, topic_key(key, topic, kind)
        self.sequence = time.time_ns() if first_sequence is None else first_sequence

    def seal(self, stamp_ns: int, *values: float, flag: bytes = b"") -> bytes:
        """The seal of the next message: ``flag``, then ``SEAL_LENGTH`` ASCII bytes (for the frame_id)."""
        self.sequence += 1
        return flag + b"%016x|" % self.sequence + seal_mac(self._key, self.kind, self.topic, self.sequence, stamp_ns,
                                                           values, flag)


def CommandSigner(key: bytes, topic: str, first_sequence: int | None = None) -> Signer:
    """The :class:`Signer` of a controller's commands on ``topic``."""
    return Signer(key, topic, "command", first_sequence)


#: What :meth:`Verifier.check` says of a seal.
AUTHENTIC, UNAUTHENTICATED, REPLAYED = "authentic", "unauthenticated", "replayed"


class Verifier:
    """Checks the seals of one ``kind`` on ``topic``: the MAC, and a sequence above the last that verified.

    ``flag_length``: the seals start with a flag of this many bytes (:data:`LOCKSTEP_FLAG`); the last authentic
    one's is :attr:`flag`.
    """

    def __init__(self, key: bytes, topic: str, kind: str = "command", flag_length: int = 0):
        self.topic, self.kind, self._key = topic, kind, topic_key(key, topic, kind)
        self._flag_length, self._length = flag_length, flag_length + SEAL_LENGTH
        self.last_sequence = -1
        self.flag = b""

    def check(self, seal: bytes | None, stamp_ns: int, *values: float) -> str:
        """AUTHENTIC (and the sequence recorded), UNAUTHENTICATED (no seal, malformed, a MAC that does not
        verify) or REPLAYED (a MAC that verifies on a sequence at or below the last one)."""
        if seal is None or len(seal) != self._length:
            return UNAUTHENTICATED
        flag, seal = seal[:self._flag_length], seal[self._flag_length:]
        if seal[SEQUENCE_DIGITS] != ord("|") or not _HEX.issuperset(seal[:SEQUENCE_DIGITS]):
            return UNAUTHENTICATED
        sequence = int(seal[:SEQUENCE_DIGITS], 16)
        expected = seal_mac(self._key, self.kind, self.topic, sequence, stamp_ns, values, flag)
        if not hmac.compare_digest(seal[SEQUENCE_DIGITS + 1:], expected):
            return UNAUTHENTICATED
        if sequence <= self.last_sequence:
            return REPLAYED
        self.last_sequence, self.flag = sequence, flag
        return AUTHENTIC


def CommandVerifier(key: bytes, topic: str) -> Verifier:
    """The :class:`Verifier` of the commands on ``topic`` (the plant's)."""
    return Verifier(key, topic, "command")


def MeasurementVerifier(key: bytes, topic: str) -> Verifier:
    """The :class:`Verifier` of a plant's measurements on ``topic`` (``/gen1/pmu``): their seals carry its mode."""
    return Verifier(key, topic, "measurement", FLAG_LENGTH)
