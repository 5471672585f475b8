"""Benchmarks behind `htdata bench`: each returns rows (dicts); bench.py runs them side by side."""
