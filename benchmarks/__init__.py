"""Benchmark commands: each prints a table; none is a test.

Not part of the installed package (setup.py packages only clusterfem_ros and msg_adapters): run them from
the repository root, ``python -m benchmarks.<name>``, with the package importable (scripts/env.sh).
"""
