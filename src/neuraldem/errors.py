"""Errors a user can fix. Entry points print them as one line (no traceback) and exit with status 2.

Each message names what is wrong (the file, field or config key) and how to fix it.
"""


class NeuraldemError(Exception):
    """Base class: a problem with the user's input or environment, not a bug in neuraldem.

    `problem` says what is wrong, `fix` (optional) what to do; the message is both, joined by ': '."""

    def __init__(self, problem: str, fix: str | None = None):
        self.problem, self.fix = problem, fix
        super().__init__(f"{problem}: {fix}" if fix else problem)


class ConfigError(NeuraldemError):
    """A config value is missing, of the wrong type or out of range."""


class DataError(NeuraldemError):
    """A dataset or file is missing, malformed, truncated or of another schema."""


class SolverError(NeuraldemError):
    """A solver (LIGGGHTS, OpenFOAM) is missing, misconfigured, or a run failed."""


class SolverInterrupted(NeuraldemError):
    """A solver process was stopped by a signal from outside (kill, shutdown, OOM killer): the simulation is
    unfinished, not failed, so it stays pending and the next run of the same command resumes it."""
