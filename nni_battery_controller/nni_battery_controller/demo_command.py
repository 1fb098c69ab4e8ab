"""``nni-demo``: the distributed closed loop of the SMIB generator, or with ``--case`` of a network of generators.

Dispatch only: a command line naming ``--case`` goes to
:mod:`nni_battery_controller.network_demo`, any other to
:mod:`nni_battery_controller.smib_demo`; each has its own options and ``--help``.
"""

from __future__ import annotations

import sys

from nni_msgs_adapter.ros.cli_support import given_options


def main(argv=None) -> int:
    """Entry point of ``nni-demo``: imports only the demo it runs (each loads its own half of the project)."""
    if "--case" in given_options(sys.argv[1:] if argv is None else argv):
        from nni_battery_controller import network_demo

        return network_demo.main(argv)
    from nni_battery_controller import smib_demo

    return smib_demo.main(argv)


if __name__ == "__main__":
    sys.exit(main())
