"""Datasets in the formats of other learned simulators (GNS npz, LagrangeBench HDF5), written and read back.

`formats.py`: the two layouts, the exit rules, the statistics, the reader; `__main__.py`: the `neuraldem export`
command (reads a dataset's runs through `gns.datamodule.ParticleRun`); `datamodule.py`: the GNS baseline
trained from an export. docs/exports.md.
"""
