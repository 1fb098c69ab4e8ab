"""nni_battery_controller."""
