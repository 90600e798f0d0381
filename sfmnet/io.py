"""Writing result files so that a crash never leaves half a file behind."""

from __future__ import annotations

import csv
import errno
import io
import json
import math
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from sfmnet.errors import SfmnetError

# What to do when writing fails, by errno; anything else: check the path.
WRITE_REMEDIES = {
    errno.EACCES: "choose a folder you may write to, or change its permissions",
    errno.EPERM: "choose a folder you may write to, or change its permissions",
    errno.EROFS: "its file system is read-only: choose a folder on a writable one",
    errno.ENOSPC: "the disk is full: free some space or write elsewhere",
    errno.EDQUOT: "the disk quota is used up: free some space or write elsewhere",
    errno.EISDIR: "that is a folder: give the name of a file to write",
    errno.EEXIST: "a file stands where a folder is needed: choose another path",
    errno.ENOTDIR: "a file stands where a folder is needed: choose another path",
}


def refuse_overwrite(path: Path, overwrite: bool, setting: str, example: str, allow: str) -> None:
    """Refuse to write ``path`` where it is a folder, or a file that exists and ``overwrite`` is not given: nothing a
    user made is replaced.

    Args:
        setting: how the user names the path in the message (``"output="`` on the command line, ``""`` in Python);
        example: a file name to suggest inside a folder; allow: how to say overwriting is meant.
    """
    if path.is_dir():
        raise SfmnetError(f"{setting}{path} is a folder: give the file to write, e.g. {setting}{path / example}")
    if path.exists() and not overwrite:
        raise SfmnetError(f"{path} already exists: choose another {setting or 'path'} or {allow}")


def write_error(path: Path, error: OSError) -> SfmnetError:
    """One line for a file-system error while writing ``path``: the path, the cause and what to do."""
    remedy = WRITE_REMEDIES.get(error.errno, "check the path and its folders")
    return SfmnetError(f"cannot write {path} ({error.strerror or error}): {remedy}")


def check_writable_dir(path: Path, option: str) -> None:
    """Refuse, naming ``option``, a folder that cannot be made or written: a file there or above it, or no permission.

    Nothing is created: the nearest existing folder of ``path`` is only looked at.
    """
    path = Path(path)
    existing = next(folder for folder in [path, *path.parents] if folder.exists() or folder == folder.parent)
    if not existing.is_dir():
        raise SfmnetError(f"{path} cannot be a folder: {existing} is a file; choose another {option}")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise SfmnetError(
            f"{path} cannot be written: {existing} is read-only for you; choose another {option} or change its permissions"
        )


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path``, then rename it into place; a file-system error is one line."""
    path = Path(path)
    try:
        handle, temporary = temporary_beside(path, ".tmp")
    except OSError as error:
        raise write_error(path, error) from None
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(data)
        os.replace(temporary, path)
    except BaseException as error:
        Path(temporary).unlink(missing_ok=True)
        if isinstance(error, OSError):
            raise write_error(path, error) from None
        raise


def temporary_beside(path: Path, suffix: str) -> tuple[int, str]:
    """A new file in ``path``'s folder (made if missing) to be renamed onto ``path``: an open handle and its name.

    ``mkstemp`` makes it private (0600); it gets the mode any new file would (``0666 & ~umask``),
    so what is renamed into place (outputs, a shared data folder's cache) stays readable to others.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    # The umask can only be read by setting it, so it is set straight back.
    umask = os.umask(0o022)
    os.umask(umask)
    os.fchmod(handle, 0o666 & ~umask)
    return handle, temporary


def write_text_atomic(path: Path, text: str) -> None:
    write_bytes_atomic(path, text.encode())


def save_figure_atomic(figure: Any, path: Path, dpi: int = 110) -> None:
    """A matplotlib figure as PNG, written atomically."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    write_bytes_atomic(path, buffer.getvalue())


def save_npz_atomic(path: Path, **arrays: Any) -> None:
    """``numpy.savez`` of ``arrays``, written atomically."""
    import numpy as np

    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    write_bytes_atomic(path, buffer.getvalue())


def strict_json_values(payload: Any) -> Any:
    """``payload`` with every NaN or infinite float as None: JSON has no such numbers, and a strict parser (most
    outside Python) refuses the ``NaN`` and ``Infinity`` that ``json.dumps`` writes by default."""
    if isinstance(payload, float):
        return payload if math.isfinite(payload) else None
    if isinstance(payload, dict):
        return {key: strict_json_values(value) for key, value in payload.items()}
    if isinstance(payload, (list, tuple)):
        return [strict_json_values(value) for value in payload]
    return payload


def write_json_atomic(path: Path, payload: Any) -> None:
    """``payload`` as standard JSON (an undefined figure, NaN or infinite, as ``null``), written atomically."""
    text = json.dumps(strict_json_values(payload), indent=2, sort_keys=True, allow_nan=False)
    write_text_atomic(path, text + "\n")


def write_csv_atomic(path: Path, header: list[str], rows: Iterable[Iterable[Any]], delimiter: str = ",") -> None:
    """A CSV with ``header`` then ``rows`` (cells separated by ``delimiter``), written atomically like
    :func:`write_text_atomic`."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, delimiter=delimiter)
    writer.writerow(header)
    writer.writerows(rows)
    write_text_atomic(path, buffer.getvalue())
