"""The GNS baseline's benchmark adapters (its points on the speed-accuracy chart, its stability map)."""
