"""The files a run reads: each must be a regular file, checked before anything opens it (a FIFO would hang a read)."""

from __future__ import annotations

import stat
from pathlib import Path

from sfmnet.errors import SfmnetError

# What a path is when it is not a regular file, by its file-type bits.
SPECIAL_KINDS = {
    stat.S_IFDIR: "a directory",
    stat.S_IFIFO: "a FIFO (named pipe)",
    stat.S_IFSOCK: "a socket",
    stat.S_IFCHR: "a character device",
    stat.S_IFBLK: "a block device",
}


def special_kind(path: Path) -> str | None:
    """What ``path`` is when it exists but is not a regular file (following links), else None."""
    try:
        mode = Path(path).stat().st_mode
    except OSError:
        return None
    return None if stat.S_ISREG(mode) else SPECIAL_KINDS.get(stat.S_IFMT(mode), "not a regular file")


def check_input_file(path: Path, option: str, expected: str) -> Path:
    """``path`` if it is a regular file that exists; else one line naming what it is and the ``option`` to fix.

    ``expected`` says what the option needs, e.g. ``a file (.csv, .npy or .npz)``. A leading ``~`` is the home
    folder, as a shell would read it unquoted.
    """
    path = Path(path).expanduser()
    try:
        path.stat()
    except FileNotFoundError:
        # A relative path is taken from where the command runs, which a user who moved elsewhere may not expect.
        where = "" if path.is_absolute() else f" (relative to {Path.cwd()}, the folder you run in)"
        raise SfmnetError(f"{path} does not exist{where}: check {option}") from None
    except PermissionError:
        raise SfmnetError(f"{path} cannot be reached (permission denied): check {option} and the folders' permissions") from None
    except OSError as error:
        raise SfmnetError(f"{path} cannot be read ({error.strerror}): check {option}") from None
    kind = special_kind(path)
    if kind:
        raise SfmnetError(f"{path} is {kind}, not a regular file: {option} needs {expected} saved on disk")
    return path
