"""The hopper's parameter table: the one place its parameters are declared (`scenes/parameters.py`)."""

from neuraldem.scenes.parameters import Parameter, ParameterTable

# what a user may sample (datagen ranges) and ask (what-if values): the physically sensible limits of each
PARAMETERS = ParameterTable((
    Parameter("alpha", "deg", 0.0, 75.0, "cone angle to the horizontal (0 = flat bottom)"),
    Parameter("mu_s", "", 0.0, 2.0, "sliding friction coefficient (particle-particle and particle-wall)"),
    Parameter("mu_r", "", 0.0, 1.0, "rolling friction coefficient (EPSD2 rolling model)"),
))
