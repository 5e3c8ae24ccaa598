"""Datasets: HDF5 schema, manifest, fields computed from particles, splits and datamodules."""
