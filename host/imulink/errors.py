"""The root of every error imulink reports to a user.

Each layer raises its own subclass (a link that fails, a damaged recording, a setting out of
range, ...); the command line catches this one class and prints its message in one line.
"""


class ImulinkError(Exception):
    """A failure a user can act on, said in one line (no traceback)."""
