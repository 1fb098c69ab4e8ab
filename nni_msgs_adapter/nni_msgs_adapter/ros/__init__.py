"""The message contract and node plumbing: topics, QoS, conversions, node start-up, parameters, process supervision, defaults."""
