"""Benchmarks (not tests): `python -m neuraldem.bench NAME [args]` writes `results/<question>/NAME.json` (the folder
of its question, `report.RESULT_FOLDERS`: results/hopper/speed/, results/fluidized_bed/stability/, ...).

Run `python -m neuraldem.bench` without arguments to list them.
"""
