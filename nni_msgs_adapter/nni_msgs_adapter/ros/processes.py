"""Child processes for nni-demo, the bench and the tests: one supervisor, no ROS import.

Every child runs in a session of its own (a Ctrl-C on the terminal reaches the
parent only, which stops its children in order) and gets the parent-death
signal SIGTERM (Linux ``prctl(PR_SET_PDEATHSIG)``): killed with SIGKILL, the
parent takes its children with it, and the nodes finish their files as on
SIGINT. Output goes to one log file per child.
"""

from __future__ import annotations

import ctypes
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

#: Seconds a child gets to exit after SIGINT before SIGKILL.
STOP_GRACE_S = 10.0
#: Linux prctl option: the signal a process gets when its parent dies.
_PR_SET_PDEATHSIG = 1
#: The number of DDS participants (ROS processes) a deployment starts on this host, in its children's
#: environment: above 32 their discovery range is widened to cover them (node_main.select_dds_profile).
PARTICIPANTS_ENV = "NNI_DDS_PARTICIPANTS"


class ChildError(RuntimeError):
    """A child exited or stayed silent where the caller waited for it (message: what, and its log's tail)."""


def node_command(module: str, params: dict | None = None, ros_args: tuple = ()) -> list[str]:
    """``python -m module --ros-args [ros_args] -p k:=v ...``, values as ROS command-line YAML."""
    args = list(ros_args)
    for key, value in (params or {}).items():
        args += ["-p", f"{key}:={parameter_text(value)}"]
    return [sys.executable, "-m", module, *(["--ros-args", *args] if args else [])]


def with_participants(env: dict, participants: int) -> dict:
    """``env`` for a deployment of ``participants`` processes on this host (``NNI_DDS_PARTICIPANTS``)."""
    return {**env, PARTICIPANTS_ENV: str(int(participants))}


def parameter_text(value) -> str:
    """A parameter value as ROS command-line YAML (.inf for inf, true/false for bools, strings quoted, lists of them).

    Strings are single-quoted so that YAML keeps them strings whatever they hold
    (a JSON object, "true", a number).
    """
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(parameter_text(item) for item in value) + "]"
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and math.isinf(value):
        return ".inf" if value > 0 else "-.inf"
    return str(value)


def _die_with_parent(parent_pid: int) -> None:
    """preexec_fn: SIGTERM when the parent dies; the parent may have died before prctl took effect."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    if os.getppid() != parent_pid:
        os.kill(os.getpid(), signal.SIGTERM)


class Child:
    """One child process with its log file."""

    def __init__(self, name: str, cmd: list[str], env: dict, log_path: Path, cwd: Path | None = None):
        self.name, self.log_path, self._killed_after_s = name, log_path, None
        self._log = open(log_path, "wb")
        parent = os.getpid()
        self.proc = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=self._log, stderr=subprocess.STDOUT,
                                     start_new_session=True, preexec_fn=lambda: _die_with_parent(parent))

    @property
    def pid(self) -> int:
        return self.proc.pid

    def poll(self) -> int | None:
        return self.proc.poll()

    def wait(self, timeout: float) -> int:
        """Exit status, or subprocess.TimeoutExpired after ``timeout`` s."""
        return self.proc.wait(timeout=timeout)

    def wait_exit(self, timeout_s: float) -> int:
        """Exit status; ChildError (with the log's tail) if the child is still running after ``timeout_s``."""
        try:
            return self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise ChildError(f"{self.name} did not finish within {timeout_s:.0f} s: {self.tail()}") from None

    def stop(self, grace_s: float = STOP_GRACE_S) -> int:
        """SIGINT and wait; SIGKILL if it does not exit within ``grace_s``. Returns the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=grace_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                self._killed_after_s = grace_s
        self._log.close()
        return self.proc.returncode

    def how_it_ended(self) -> str:
        """How the finished child ended, for a message: ``exited with status 1``, ``died of SIGSEGV``, ..."""
        status = self.proc.returncode
        if self._killed_after_s is not None:
            return f"did not exit within {self._killed_after_s:g} s of SIGINT and was killed"
        if status is not None and status < 0:
            try:
                return f"died of {signal.Signals(-status).name}"
            except ValueError:  # a real-time signal without a name of its own
                return f"died of signal {-status}"
        return f"exited with status {status}"

    def kill(self) -> None:
        """SIGKILL (a crash)."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def output(self) -> str:
        """Everything the child printed so far."""
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def tail(self, chars: int = 300) -> str:
        return self.output().strip()[-chars:]

    def last_line(self) -> str:
        """The last line the child printed (a node's one-line error when it stopped), or ``(nothing printed)``."""
        return (self.output().strip().splitlines() or ["(nothing printed)"])[-1]

    def wait_for_line(self, prefix: str, timeout_s: float, accept=lambda line: True) -> str:
        """The first printed line that starts with ``prefix`` (after any log decoration) and that ``accept``s.

        Raises ChildError if the child exits or ``timeout_s`` passes first.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            for line in self.output().splitlines():
                at = line.find(prefix)
                if at >= 0 and accept(line[at:]):
                    return line[at:]
            if self.proc.poll() is not None:
                raise ChildError(f"{self.name} {self.how_it_ended()}: {self.tail()}")
            if time.monotonic() > deadline:
                raise ChildError(f"{self.name} printed no {prefix.strip()!r} line within {timeout_s:g} s: "
                                 f"{self.tail()}")
            time.sleep(0.05)


class Supervisor:
    """A group of children; all stopped (SIGINT, then SIGKILL), last started first, when the block ends."""

    def __init__(self, env: dict, log_dir: Path, cwd: Path | None = None, grace_s: float = STOP_GRACE_S):
        self.env, self.log_dir, self.cwd, self.grace_s = env, Path(log_dir), cwd, grace_s
        self.children: dict[str, Child] = {}

    def start(self, name: str, cmd: list[str], env: dict | None = None) -> Child:
        """Start ``cmd`` as child ``name``, with ``env`` added to the supervisor's environment."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        child = Child(name, cmd, {**self.env, **(env or {})}, self.log_dir / f"{name}.log", self.cwd)
        self.children[name] = child
        return child

    def start_node(self, name: str, module: str, params: dict | None = None, ros_args: tuple = (),
                   env: dict | None = None) -> Child:
        return self.start(name, node_command(module, params, ros_args), env)

    def __getitem__(self, name: str) -> Child:
        return self.children[name]

    def stop_all(self) -> None:
        for child in reversed(list(self.children.values())):
            child.stop(self.grace_s)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop_all()
