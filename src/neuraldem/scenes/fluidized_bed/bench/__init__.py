"""Scene benchmarks: adapters that feed the shared bench primitives."""
