"""Benchmarks of the loop and the region-of-attraction sweep: ``python -m bench``."""
