"""Exception types shared by the whole workbench.

The CLI turns every one of these into a single line on stderr and exit code 2.
"""


class ConfigError(ValueError):
    """A parameter file, scenario or option is malformed (names the field)."""


class DataError(ValueError):
    """A log or measurement is malformed (names the column and row)."""


class SolverFailure(RuntimeError):
    """A numerical solver did not return a usable solution."""
