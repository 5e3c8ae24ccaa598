"""Solver drivers: write inputs, run LIGGGHTS / OpenFOAM, read their outputs into arrays."""
