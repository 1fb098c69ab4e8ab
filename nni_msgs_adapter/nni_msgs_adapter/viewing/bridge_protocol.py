"""What the Rerun bridge prints for the demos to read, and whether a native viewer can open (no rclpy, no rerun).

The demos wait for these lines of the bridge's output; they import this
module instead of the bridge, which would load rclpy and rerun into a
process that only starts the bridge as a child.
"""

from __future__ import annotations

import os
import sys

#: Logged once the subscriptions exist; nni-demo waits for it before the first run.
READY_TEXT = "rerun bridge ready"
#: Printed (then a JSON object) whenever a run's logged sample count changes.
PROGRESS_PREFIX = "rerun bridge run: "
#: Before the web viewer's URL: the bridge logs it (sink serve), nni-demo --rerun serve prints it.
URL_TEXT = "Rerun web viewer:"


def display_missing() -> bool:
    """True where a native viewer cannot open a window (Linux without X11 or Wayland)."""
    return sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
