"""The one exception type for problems a user can fix (bad data, bad options)."""


class SfmnetError(Exception):
    """A problem with the user's input. The message is one line: the cause, then the remedy.

    The command line prints it without a traceback and exits with status 2.
    """
