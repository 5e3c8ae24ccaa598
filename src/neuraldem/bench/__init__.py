"""Benchmarks (not tests): `python -m neuraldem.bench NAME [args]` writes `results/bench/NAME.json`.

Run `python -m neuraldem.bench` without arguments to list them.
"""
