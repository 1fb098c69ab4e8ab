"""``main()`` plumbing shared by the nodes: start, spin, clean shutdown, one-line errors.

SIGINT and SIGTERM only ask the spin loop to stop; the node's ``close()`` then
runs with the ROS context still valid (final diagnostics go out, files are
finished) and the process exits 0. rclpy's own handlers are not installed: they
would invalidate the context before ``close()`` could publish. Invalid start-up
parameters print one line naming the problem and exit 2.
"""

from __future__ import annotations

import signal
import sys

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from nni_msgs_adapter.cli_support import EXIT_USAGE

#: Longest wait inside the executor, s: how soon a signal is noticed.
_SIGNAL_POLL_S = 0.05


def run_node(factory, args=None, prog: str = "node") -> int:
    """Construct ``factory()`` and spin it until a signal or until it reports done.

    A node may offer ``done`` (an rclpy Future completed when its run is over,
    e.g. the plant after its duration) and ``close()`` (called before it is
    destroyed, still able to publish).
    """
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = factory()
    except (ValueError, ParameterException) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return EXIT_USAGE
    stop = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda number, frame: stop.append(number))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    done = getattr(node, "done", None)
    try:
        while not stop and not (done is not None and done.done()):
            executor.spin_once(timeout_sec=_SIGNAL_POLL_S)
    finally:
        close = getattr(node, "close", None)
        if close is not None:
            close()
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
