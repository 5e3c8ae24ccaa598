"""NeuralDEM: multi-branch neural operator surrogates for DEM and CFD-DEM particulate flows.

Data flows one way: sim -> data -> models -> lit -> eval -> scenes -> commands (docs/architecture.md).
"""

import time

__version__ = "0.1.0"
STARTED = time.perf_counter()  # when the package was first imported: what a command's answer time counts from
