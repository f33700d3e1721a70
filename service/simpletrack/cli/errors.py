"""The one error a command raises for a mistake of its user's."""

USAGE_EXIT = 2  # a command's exit code for it (a supervisor reads it as "will not start")


class UserError(Exception):
    """A mistake in the command's arguments or inputs: printed as one line, exit code 2."""
