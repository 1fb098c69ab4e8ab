"""IEEE C37.118.2-2011 synchrophasor streams: the frame codec, the byte-stream reassembler, the PMU server and
the PDC client cores (no ROS import)."""
