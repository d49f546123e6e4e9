"""Errors of the trajectory database and its build, importable without the planning stack (the CLI's handler)."""


class DatabaseError(RuntimeError):
    """The trajectory database is missing, corrupt, of another schema, or locked."""


class BuildError(RuntimeError):
    """A unit of a catalog build failed; the units committed before it stay."""
