"""Surrogate."""
