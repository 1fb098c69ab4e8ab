"""nni_msgs_adapter."""
