"""The one exception type for problems a user can fix (bad data, bad options)."""


class SfmnetError(Exception):
    """A problem with the user's input. The message is one line: the cause, then the remedy.

    The command line prints it without a traceback and exits with status 2.
    """


class FitInterrupted(SfmnetError):
    """The user stopped a fit (Ctrl-C). The message names the checkpoint to resume from.

    The command line prints it as ``interrupted: ...`` and exits with status 130, as a shell does
    for a process ended by SIGINT.
    """

    exit_status = 130

    def __init__(self, message: str, stopped: str = "") -> None:
        super().__init__(message)
        self.stopped = stopped  # which fit stopped where, e.g. "LinearAutoencoder stopped in epoch 4"
