"""``nni-replay`` (``ros2 run nni_battery_controller replay``): play a recording back, view it, describe it.

The entry point: the command line and its dispatch to one job, each in a module named after it.

ROS playback, the default (:mod:`replay_ros`)::

    nni-replay run.mcap [--rate FACTOR] [--loop] [--start-offset S] [--clock]
                        [--wait-for-subscribers N] [--wait-topic TOPIC] [--domain-id N]

Rerun, no ROS graph (:mod:`replay_rerun`)::

    nni-replay run.mcap --rrd out.rrd | --connect [URL|PORT] | --spawn

Description and figure, no ROS graph (:mod:`replay_info`, :mod:`replay_plot`)::

    nni-replay run.mcap --info            # what `ros2 bag info` shows, the run's parameters, its verdicts
    nni-replay run.mcap --plot out.png    # the run's figure (nni-simulate's, from the recorded samples)

IEEE C37.118.2 to PDCs at the recorded rate, no ROS graph (:mod:`replay_c37118`)::

    nni-replay run.mcap --pmu-server [HOST:]PORT [--pmu-idcode N] [--pmu-wait-for-pdcs N]

Every job reads the recording through :mod:`replay_load`. The options of one job are
refused with another, with one line naming them.

A recording cut short (a killed logger, a full disk) is read up to its last flush and
reported as incomplete (how many messages, up to which time): ``--info`` says so, every
other use refuses it unless ``--allow-partial``. Bad input (missing, non-regular,
non-MCAP, oversized or unrecoverably cut file, a recording without ``plant/state``, an
unknown message type or one the contract does not give the topic, a viewer that is not
there, no display for ``--spawn``) prints one line and exits 2; the ``.rrd`` appears whole
or not at all.
"""

from __future__ import annotations

import sys

from nni_msgs_adapter.c37118.cli import add_pmu_options, refuse_without_server
from nni_msgs_adapter.ros.cli_support import (
    CliError, OneLineParser, finite_float, positive_float, run_cli, writable_output,
)
from nni_battery_controller.replay_c37118 import serve
from nni_battery_controller.replay_info import describe
from nni_battery_controller.replay_load import PROG
from nni_battery_controller.replay_plot import plot
from nni_battery_controller.replay_rerun import DEFAULT_VIEWER_PORT, connect_url, convert
from nni_battery_controller.replay_ros import DEFAULT_WAIT_FOR_SUBSCRIBERS, play

_ROS_ONLY = {"rate": 1.0, "loop": False, "start_offset": 0.0, "clock": False,
             "wait_for_subscribers": DEFAULT_WAIT_FOR_SUBSCRIBERS, "wait_topic": None, "domain_id": None}
_RERUN_ONLY = {"f0_hz": None}


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    import argparse

    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def build_parser() -> OneLineParser:
    """The nni-replay command line."""
    parser = OneLineParser(prog=PROG, description="Replay an NNI MCAP recording on ROS 2, view it in Rerun, "
                                                  "describe it, draw its figure or serve it to PDCs as C37.118.")
    parser.add_argument("recording", help="MCAP file (ROS 2 profile), e.g. recordings/paper_b0.3.mcap")
    parser.add_argument("--allow-partial", action="store_true",
                        help="use a recording cut short (killed logger, full disk) up to its last flush "
                             "(default: refused; --info always describes it)")
    ros = parser.add_argument_group("ROS playback (default)")
    ros.add_argument("--rate", type=positive_float, default=1.0, help="speed factor (2: twice as fast)")
    ros.add_argument("--loop", action="store_true", help="start again after the last message, until stopped")
    ros.add_argument("--start-offset", type=non_negative_float, default=0.0, metavar="S",
                     help="skip the first S seconds of the recording (latched topics still go out)")
    ros.add_argument("--clock", action="store_true", help="publish /clock with the recording's time at 40 Hz")
    ros.add_argument("--wait-for-subscribers", type=int, default=DEFAULT_WAIT_FOR_SUBSCRIBERS, metavar="N",
                     help="start once N subscribers listen, each matched on every replayed topic it subscribes to, "
                          f"and discovery has settled (default {DEFAULT_WAIT_FOR_SUBSCRIBERS}; 0: at once)")
    ros.add_argument("--wait-topic", metavar="TOPIC", default=None,
                     help="count only the subscribers of this replayed topic (default: of any replayed topic)")
    ros.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: the environment's)")
    view = parser.add_argument_group("Rerun instead of ROS")
    sink = view.add_mutually_exclusive_group()
    sink.add_argument("--rrd", type=writable_output, metavar="OUT.rrd", help="write a Rerun recording file")
    sink.add_argument("--connect", metavar="URL", type=connect_url, nargs="?",
                      const=f"rerun+http://127.0.0.1:{DEFAULT_VIEWER_PORT}/proxy",
                      help="stream to a running viewer or server: its gRPC URL or port "
                           f"(default rerun+http://127.0.0.1:{DEFAULT_VIEWER_PORT}/proxy)")
    sink.add_argument("--spawn", action="store_true", help="start a native viewer and stream to it")
    view.add_argument("--f0-hz", type=positive_float, default=None,
                      help="nominal frequency, Hz, to label a recording without run parameters "
                           "(refused when the recording has them: it says f0 itself)")
    about = parser.add_argument_group("Describe or draw (no ROS, no Rerun)")
    what = about.add_mutually_exclusive_group()
    what.add_argument("--info", action="store_true",
                      help="print what `ros2 bag info` shows, whether the file is complete, the run's parameters "
                           "and its verdicts")
    what.add_argument("--plot", type=writable_output, metavar="OUT.png", help="draw the run's figure")
    add_pmu_options(parser, "the recording's PMU measurements at its rate (no ROS, no Rerun)", "the stream")
    return parser


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """``(own arguments, ROS arguments)``: ``--ros-args ... [--]`` is rclpy's (as ``ros2 run`` passes it)."""
    own, ros, in_ros = [], [], False
    for arg in argv:
        if arg == "--ros-args":
            in_ros = True
        elif in_ros and arg == "--":
            in_ros = False
            continue
        (ros if in_ros else own).append(arg)
    return own, ros


def refuse_options(args, ros_args: list[str], defaults: dict, kind: str, use: str) -> None:
    """CliError naming every option of ``defaults`` set away from its default (and ``--ros-args``) for ``use``."""
    misplaced = ["--" + name.replace("_", "-") for name, default in defaults.items() if getattr(args, name) != default]
    if ros_args:
        misplaced.append("--ros-args")
    if misplaced:
        raise CliError(f"{', '.join(misplaced)}: {kind}, not for {use}")


def main(argv=None) -> int:
    """Entry point of ``nni-replay`` and ``ros2 run nni_battery_controller replay``."""
    own, ros_args = split_ros_args(sys.argv[1:] if argv is None else list(argv))
    parser = build_parser()

    def body() -> int:
        args = parser.parse_args(own)
        if args.wait_for_subscribers < 0:
            raise CliError(f"--wait-for-subscribers must be >= 0, got {args.wait_for_subscribers}")
        refuse_without_server(args, own)
        viewing = args.rrd is not None or args.connect is not None or args.spawn
        describing = args.info or args.plot is not None
        if viewing and describing:
            raise CliError("--info/--plot: not with --rrd/--connect/--spawn (one output at a time)")
        if args.pmu_server is not None:
            if viewing or describing:
                raise CliError("--pmu-server: not with --rrd/--connect/--spawn/--info/--plot (one output at a time)")
            refuse_options(args, ros_args, _ROS_ONLY, "ROS playback options", "--pmu-server")
            refuse_options(args, [], _RERUN_ONLY, "a Rerun option", "--pmu-server")
            return serve(args)
        if viewing or describing:
            refuse_options(args, ros_args, _ROS_ONLY, "ROS playback options",
                           "--rrd/--connect/--spawn" if viewing else "--info/--plot")
        if describing:
            refuse_options(args, [], _RERUN_ONLY, "a Rerun option", "--info/--plot")
            return describe(args) if args.info else plot(args)
        if viewing:
            return convert(args)
        refuse_options(args, [], _RERUN_ONLY, "a Rerun option", "ROS playback")
        return play(args, ros_args)

    return run_cli(body, PROG)


if __name__ == "__main__":
    sys.exit(main())
