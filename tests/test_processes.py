"""The process supervisor says how a child ended, as the demos' failure lines quote it."""

import sys

from nni_msgs_adapter.ros.processes import Child

IGNORES_SIGINT = "import signal, time\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\nprint('ready', flush=True)\ntime.sleep(60)"


def child(tmp_path, name: str, code: str) -> Child:
    return Child(name, [sys.executable, "-c", code], {}, tmp_path / f"{name}.log")


def test_an_exit_status_a_signal_and_a_kill_after_the_grace_are_told_apart(tmp_path):
    exited = child(tmp_path, "exited", "import sys; sys.exit(3)")
    assert exited.wait(30.0) == 3 and exited.stop() == 3
    assert exited.how_it_ended() == "exited with status 3"

    segfault = child(tmp_path, "segfault", "import os, signal; os.kill(os.getpid(), signal.SIGSEGV)")
    assert segfault.wait(30.0) == -11
    assert segfault.how_it_ended() == "died of SIGSEGV"

    stubborn = child(tmp_path, "stubborn", IGNORES_SIGINT)
    stubborn.wait_for_line("ready", 30.0)
    assert stubborn.stop(grace_s=0.5) == -9
    assert stubborn.how_it_ended() == "did not exit within 0.5 s of SIGINT and was killed"
