"""K DDS participants in one process, and which of them discovered which (tests/test_many_participants.py).

``python tests/many_participants.py K WAIT_S``: chooses the DDS profile as every node of ours does
(``node_main.select_dds_profile``, reading ``NNI_DDS_PARTICIPANTS`` and ``NNI_NETWORK`` from the
environment), then creates K rclpy Contexts (each one DDS participant, as a process of ours is) with one
node ``p<i>`` each, in order, and waits until every node's graph holds all K nodes or WAIT_S seconds pass.
Prints one JSON line: for each node in creation order, the ``p<j>`` it sees, and the seconds waited.
"""

from __future__ import annotations

import json
import os
import sys
import time

import rclpy
from rclpy.context import Context

from nni_msgs_adapter.ros.node_main import select_dds_profile


def main(count: int, wait_s: float) -> None:
    select_dds_profile(os.environ)
    contexts, nodes = [], []
    for index in range(count):
        context = Context()
        rclpy.init(context=context)
        contexts.append(context)
        nodes.append(rclpy.create_node(f"p{index}", context=context))
    everyone = {f"p{index}" for index in range(count)}
    started = time.monotonic()

    def seen() -> list[list[str]]:
        return [sorted(name for name, _ in node.get_node_names_and_namespaces() if name in everyone) for node in nodes]

    while time.monotonic() - started < wait_s and not all(len(names) == count for names in seen()):
        time.sleep(0.1)
    print(json.dumps({"seen": seen(), "waited_s": round(time.monotonic() - started, 2)}), flush=True)
    for node, context in zip(nodes, contexts):
        node.destroy_node()
        rclpy.shutdown(context=context)


if __name__ == "__main__":
    main(int(sys.argv[1]), float(sys.argv[2]))
