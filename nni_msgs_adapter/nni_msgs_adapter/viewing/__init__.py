"""Viewing: the Rerun view of runs (recorded and live), the live bridge node, colours per run."""
