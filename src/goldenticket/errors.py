"""The one error type users see: a bad input, reported as one line and exit code 2."""


class UserError(ValueError):
    """A problem with what the user asked for (name, file, range, budget), not a bug."""
