"""The fluidized bed's parameter table: the one place its parameters are declared (`scenes/parameters.py`)."""

from neuraldem.scenes.parameters import Parameter, ParameterTable

# what a user may ask for at all (datagen ranges, what-if values); a model answers within its trained range
PARAMETERS = ParameterTable((
    Parameter("inlet_velocity", "m/s", 0.0, 20.0, "superficial air velocity at the bottom inlet"),
))
