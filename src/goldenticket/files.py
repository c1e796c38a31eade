"""Output files: written whole or not at all, with the user's umask."""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
from pathlib import Path

from goldenticket.errors import UserError

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISLNK, "a symbolic link"), (stat.S_ISFIFO, "a fifo"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a device"), (stat.S_ISBLK, "a device"))


def check_target(path: Path) -> None:
    """Raise UserError unless `path` is absent or a regular file. A symbolic link is refused
    even when it points to a regular file: the rename would replace the link, not its file."""
    try:
        mode = path.lstat().st_mode
    except (FileNotFoundError, NotADirectoryError):
        return
    if not stat.S_ISREG(mode):
        kind = next((name for test, name in _KINDS if test(mode)), "not a regular file")
        raise UserError(f"{path} is {kind}; name a new file or a regular file to replace")


def write_atomic(path: str | Path, data: bytes | str) -> Path:
    """Write `data` to a new temporary file beside `path`, flush it to disk, then rename it over
    `path`: a crash, a full disk or a second process writing the same file never leaves half a
    file. Permissions follow the umask, as for any new file. Only a regular file is replaced
    (`check_target`)."""
    path = Path(path)
    check_target(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.{secrets.token_hex(4)}.partial")
    try:
        fd = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(partial, path)
    except OSError as exc:  # name the file the user asked for, not the temporary one
        with contextlib.suppress(OSError):
            partial.unlink()
        raise OSError(exc.errno, exc.strerror, str(path)) from None
    return path


def new_folder_beside(path: Path) -> Path:
    """A new, empty, hidden folder beside `path` (umask permissions), to fill and then rename."""
    folder = path.parent / f".{path.name}.{secrets.token_hex(4)}.partial"
    folder.mkdir(parents=True)
    return folder
