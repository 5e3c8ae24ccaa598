"""NeuralDEM: multi-branch neural operator surrogates for DEM and CFD-DEM particulate flows.

Data flows one way: sim -> data -> models -> lit -> eval -> bench (see README).
"""

__version__ = "0.1.0"
