"""Benchmarks of the loop and the region-of-attraction sweep: ``python -m bench`` (``bench/run_all``).

A module per benchmark, each beside the BENCHMARKS.md section that reports it: ``latency`` (sections 1 and 1b),
``lockstep`` (2), ``roa`` (3), ``network_lockstep`` (4), ``network_realtime`` (5 and 6). ``common`` holds the runs
they are made of, ``machine`` the machine's description, ``report`` assembles the page, ``pingpong`` is the bare
rclpy floor, ``__main__`` the command line.
"""
