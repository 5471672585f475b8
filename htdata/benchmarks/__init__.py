"""Benchmarks behind `htdata bench`: each returns rows (dicts); suite.py runs them side by side, report.py renders REPORT.md."""
