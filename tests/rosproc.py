"""Real ROS 2 processes and an in-test probe node for the multi-process tests.

Nodes run as separate processes over Fast DDS on localhost
(ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) in a domain of the test's own; the probe
is an rclpy node in the test process, in its own context on the same domain.
Nothing here mocks ROS.
"""

from __future__ import annotations

import atexit
import fcntl
import itertools
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from nni_msgs_adapter.ros import command_auth
from nni_msgs_adapter.ros.processes import Child, node_command

_domain_counter = itertools.count()


def _domain_range() -> range:
    """The ROS domain ids this test process may use: ``NNI_TEST_DOMAINS=LO-HI`` (inclusive), else 1..100.

    1..100 is the range safe on Linux for Fast DDS port mapping. Two test runs at once (two
    checkouts, or parallel workers) get disjoint ranges, so that no test hears another's nodes.
    """
    text = os.environ.get("NNI_TEST_DOMAINS", "1-100")
    low, _, high = text.partition("-")
    domains = range(int(low), int(high) + 1)
    if not domains or domains.start < 0 or domains.stop > 233:
        raise ValueError(f"NNI_TEST_DOMAINS must be LO-HI within 0..232, got {text!r}")
    # A pytest-xdist worker (gw0, gw1, ...) takes its own share of the range.
    worker, workers = os.environ.get("PYTEST_XDIST_WORKER"), int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if worker is not None and workers > 1:
        share = len(domains) // workers
        if share < 1:
            raise ValueError(f"NNI_TEST_DOMAINS {text} has fewer domains than the {workers} test workers")
        index = int(worker.removeprefix("gw"))
        domains = domains[index * share:(index + 1) * share]
    return domains


def fresh_domain_id() -> int:
    """A ROS domain id for one test: distinct within this run (cycling through its range), spread across runs by pid."""
    domains = _domain_range()
    return domains[(os.getpid() * 7 + next(_domain_counter)) % len(domains)]


#: The test session's command key (:mod:`nni_msgs_adapter.ros.command_auth`): every node started by a test
#: has it, as nni-demo gives its plant and controllers a run's key; removed when the session ends.
SESSION_KEY_FILE = command_auth.new_key_file()
atexit.register(command_auth.remove_key_file, SESSION_KEY_FILE)


def session_signer(topic: str) -> command_auth.CommandSigner:
    """A signer under the session's key for the command topic ``topic`` (absolute): a probe playing the controller."""
    return command_auth.CommandSigner(command_auth.read_key(SESSION_KEY_FILE), topic)


_PMU_SIGNERS: dict = {}


def sealed_pmu(msg, topic: str = "/pmu", lockstep: bool = False):
    """``msg`` (a pmu JointState, as it is now) sealed as the run's plant seals its measurements on ``topic``
    (absolute), in its mode: a probe playing the plant. Returns ``msg``."""
    signer = _PMU_SIGNERS.get(topic)
    if signer is None:
        signer = _PMU_SIGNERS[topic] = command_auth.Signer(command_auth.read_key(SESSION_KEY_FILE), topic,
                                                           "measurement")
    flag = command_auth.LOCKSTEP_FLAG if lockstep else command_auth.REALTIME_FLAG
    stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    seal = signer.seal(stamp_ns, *msg.position, *msg.velocity, *msg.effort, flag=flag)
    from nni_msgs_adapter.ros import contract

    msg.header.frame_id = contract.SEALED_ROTOR_FRAME + seal.decode()
    return msg


def ros_env(domain_id: int, **extra) -> dict:
    """Environment for a node process: localhost discovery, the given domain, the session's command key."""
    env = dict(os.environ)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain_id),
               PYTHONUNBUFFERED="1", RCUTILS_COLORIZED_OUTPUT="0",
               **{command_auth.KEY_FILE_ENV: str(SESSION_KEY_FILE)})
    env.update({k: str(v) for k, v in extra.items()})
    return env


class NodeProcess(Child):
    """A node (or any command) started as its own process, output in a log file for post-mortems.

    The project's one supervisor (:mod:`nni_msgs_adapter.ros.processes`): own session, dies with
    the test process (parent-death signal)."""

    def __init__(self, cmd: list[str], env: dict, log_path: Path):
        super().__init__(log_path.stem, cmd, env, log_path)

    def interrupt(self, timeout: float = 10.0) -> int:
        """SIGINT and wait; SIGKILL if it does not exit in time. Returns the exit status."""
        return self.stop(timeout)


#: A busy process: a core spun until the process that started it is gone (a test worker killed leaves none).
_SPIN = "import os\nparent = os.getppid()\nwhile os.getppid() == parent:\n    for _ in range(200000):\n        pass\n"
#: The busy processes this process started and has not reaped yet.
_spinners: list[subprocess.Popen] = []


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except OSError:
        return False
    return not Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"


def busy_processes(count: int = 2):
    """``count`` processes spinning on a core each (a loaded machine) for the block.

    The suite's parallel workers share them: a block that starts while another worker's is on joins its
    spinners (at least ``count`` of them run beside every block), and the last block to end stops them, so
    that two workers' loaded tests at once load the machine as one does (no worker's test sees fewer than
    ``count`` spinning beside it). Outside pytest-xdist each block has its own."""
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    return _own_busy(count) if run is None else _shared_busy(count, Path(tempfile.gettempdir()) / f"nni-busy-{run}")


@contextmanager
def _own_busy(count: int):
    busy = [subprocess.Popen([sys.executable, "-c", _SPIN]) for _ in range(count)]
    try:
        yield
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()


@contextmanager
def _shared_busy(count: int, state_file: Path):
    def update(change):
        with open(f"{state_file}.lock", "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            state = json.loads(state_file.read_text()) if state_file.exists() else {"users": 0, "pids": []}
            state = change(state)
            state_file.write_text(json.dumps(state))

    def join(state):
        pids = [pid for pid in state["pids"] if _alive(pid)]
        started = [subprocess.Popen([sys.executable, "-c", _SPIN]) for _ in range(max(0, count - len(pids)))]
        _spinners.extend(started)
        return {"users": state["users"] + 1, "pids": pids + [proc.pid for proc in started]}

    def leave(state):
        if state["users"] > 1:
            return {**state, "users": state["users"] - 1}
        for pid in state["pids"]:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        return {"users": 0, "pids": []}

    update(join)
    try:
        yield
    finally:
        update(leave)
        for proc in list(_spinners):  # reap what this worker started and someone stopped
            if proc.poll() is not None:
                _spinners.remove(proc)


@contextmanager
def node_processes(tmp_path: Path, domain_id: int):
    """Start nodes with ``start(name, module, params, ros_args, env)``; every one is stopped on exit."""
    started: list[NodeProcess] = []

    def start(name: str, module: str, params: dict | None = None, ros_args: tuple = (),
              env: dict | None = None) -> NodeProcess:
        proc = NodeProcess(node_command(module, params, ros_args), ros_env(domain_id, **(env or {})),
                           tmp_path / f"{name}.log")
        started.append(proc)
        return proc

    try:
        yield start
    finally:
        for proc in started:
            proc.interrupt(timeout=5.0)


def printed_json(output: str, prefix: str) -> dict:
    """The JSON a node printed on the line starting with ``prefix`` (a plant's summary at exit)."""
    for line in output.splitlines():
        if line.startswith(prefix):
            return json.loads(line[len(prefix):])
    raise AssertionError(f"no line starts with {prefix!r}: {output[-500:]}")


def wait_until(predicate, timeout: float, step: float = 0.02) -> bool:
    """Poll ``predicate`` until it holds or ``timeout`` s pass; its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return predicate()


class Probe:
    """An rclpy node in the test process that records topics of the contract.

    Runs in its own rclpy Context on ``domain_id``, spun in a background thread.
    """

    def __init__(self, domain_id: int, topics, namespace: str = "", node_name: str = "probe"):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        from nni_msgs_adapter.ros import contract

        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(node_name, namespace=namespace or None, context=self.context)
        self.messages: dict[str, list] = {topic: [] for topic in topics}
        self._handlers: dict[str, list] = {}
        self._publishers: dict[str, object] = {}
        self._lock = threading.Lock()
        self._subscriptions = {}
        for topic in topics:
            msg_class, name, qos = contract.recorder_endpoint(topic)
            self._subscriptions[topic] = self.node.create_subscription(msg_class, name, self._recorder(topic), qos)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _recorder(self, topic):
        def record(msg):
            with self._lock:
                self.messages[topic].append(msg)
            for handler in self._handlers.get(topic, ()):
                handler(msg)
        return record

    def on_message(self, topic, handler) -> None:
        """Call ``handler(msg)`` (on the probe's spin thread) for every message on ``topic`` from now on."""
        self._handlers.setdefault(topic, []).append(handler)

    def _spin(self):
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def _publisher(self, topic):
        from nni_msgs_adapter.ros import contract

        if topic not in self._publishers:
            self._publishers[topic] = self.node.create_publisher(*contract.endpoint(topic))
        return self._publishers[topic]

    def advertise(self, topic) -> None:
        """Make the publisher on ``topic`` now, so that the probe is a writer there before it first publishes."""
        self._publisher(topic)

    def publish(self, topic, msg) -> None:
        """Publish on a contract topic with its QoS (the publisher is made on first use)."""
        self._publisher(topic).publish(msg)

    def wait_matched(self, topic, count: int, timeout: float) -> bool:
        """Wait until ``count`` subscriptions match this probe's publisher on ``topic``."""
        publisher = self._publisher(topic)
        return wait_until(lambda: publisher.get_subscription_count() >= count, timeout)

    def take(self, topic) -> list:
        """A copy of what arrived on ``topic`` so far."""
        with self._lock:
            return list(self.messages[topic])

    def wait_for_publishers(self, topic, count: int, timeout: float) -> bool:
        """Wait until ``count`` publishers match this probe's subscription on ``topic``."""
        subscription = self._subscriptions[topic]
        return wait_until(lambda: subscription.get_publisher_count() >= count, timeout)

    def wait_for(self, topic, count: int, timeout: float) -> list:
        """Wait until ``count`` messages arrived on ``topic`` (or time out); return them."""
        wait_until(lambda: len(self.take(topic)) >= count, timeout)
        return self.take(topic)

    def close(self):
        """Stop spinning, then release DDS resources: the node goes only once its spin thread has ended.

        The thread ends within one ``spin_once`` (0.05 s) and the handler it runs; destroying the node
        or shutting the context down while it is inside ``spin_once`` can hang (seen once under load).
        """
        import rclpy

        self._stop.set()
        self._thread.join(timeout=60.0)
        if self._thread.is_alive():
            raise RuntimeError("the probe's spin thread did not end within 60 s of close()")
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
