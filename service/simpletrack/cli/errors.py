"""The one error a command raises for a mistake of its user's."""


class UserError(Exception):
    """A mistake in the command's arguments or inputs: printed as one line, exit code 2."""
