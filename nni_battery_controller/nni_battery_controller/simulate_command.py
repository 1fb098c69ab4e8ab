"""``nni-simulate``: the offline study of the SMIB generator, or with ``--case`` of a network of generators.

Dispatch only: a command line naming ``--case`` goes to
:mod:`nni_battery_controller.network_study`, any other to
:mod:`nni_battery_controller.smib_study`; each has its own options and ``--help``.
"""

from __future__ import annotations

import sys

from nni_battery_controller import network_study, smib_study
from nni_msgs_adapter.ros.cli_support import given_options


def main(argv=None) -> int:
    """Entry point of ``nni-simulate``."""
    if "--case" in given_options(sys.argv[1:] if argv is None else argv):
        return network_study.main(argv)
    return smib_study.main(argv)


if __name__ == "__main__":
    sys.exit(main())
