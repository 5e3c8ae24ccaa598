"""Benchmarks (not tests): `neuraldem bench NAME key=value ...` writes `results/<question>/NAME.json` (the folder
of its question, `report.RESULT_FOLDERS`: results/hopper/speed/, results/fluidized_bed/stability/, ...).

Run `neuraldem bench` without arguments to list them.
"""
