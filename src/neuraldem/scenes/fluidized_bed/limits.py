"""What the fluidized-bed scene accepts at all, in a module without heavy imports: `neuraldem predict fb`
checks a typed value against it before loading anything (datagen checks its config ranges against it too)."""

VELOCITY_LIMITS = (0.0, 20.0)  # [m/s] superficial inlet velocity a user may ask for
