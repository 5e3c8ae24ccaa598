"""The particle-based baseline (GNS, a learned simulator of every particle) on the hopper and the fluidized
bed: its datamodule, LightningModule, rollout and benchmarks. It sits above the scenes (it reads their stores
and scores with their metrics); the network itself is `models/gns.py`."""
