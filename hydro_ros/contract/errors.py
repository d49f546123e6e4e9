"""The package's one exception family for bad user input.

Anything a user hands the package (a machine config, a bag, a CAN log, a path id, a parameter
value, a command-line argument) that cannot be used raises an :class:`InputError` whose message is
the one line the user sees, naming the input. The CLI and the nodes catch this family only: any
other exception is a bug and surfaces with its traceback.
"""


class InputError(ValueError):
    """Bad user input; the message names the input and says what is wrong with it."""


class DatabaseError(InputError):
    """The trajectory database is missing, corrupt, of another schema, or locked."""


class BuildError(InputError):
    """A unit of a catalog build failed on its input (e.g. an infeasible start); the units committed before it stay."""
