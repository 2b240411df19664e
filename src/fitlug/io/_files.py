"""Opening an input file: its bytes, or one line naming the file and why it cannot be read.

Every reader in io opens its file through `read_bytes`, so a missing file, a directory or
an unreadable file reads the same whichever format was asked for.
"""

from __future__ import annotations

from .._errors import InputError


def read_bytes(path: str, kind: str = "file", size: int = -1) -> bytes:
    """The content of the file at `path` (its first `size` bytes when `size` >= 0).

    Args:
        path: the file.
        kind: what was expected, named when `path` is a directory ('file', 'CSV file', ...).
        size: bytes to read; -1 (default) reads the whole file.

    Raises:
        InputError: naming the file: not found, a directory, permission denied or another
            OS error.
    """
    try:
        with open(path, "rb") as fh:
            return fh.read(size)
    except FileNotFoundError:
        raise InputError(path, "file not found") from None
    except IsADirectoryError:
        raise InputError(path, f"is a directory, not a {kind}") from None
    except PermissionError:
        raise InputError(path, "cannot read file (permission denied)") from None
    except OSError as exc:
        raise InputError(path, f"cannot read file: {exc.strerror or exc}") from None
