"""Output files: written whole or not at all, with the user's umask."""

from __future__ import annotations

import contextlib
import errno
import glob
import os
import secrets
import shutil
import stat
from pathlib import Path

from goldenticket.errors import UserError

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISLNK, "a symbolic link"), (stat.S_ISFIFO, "a fifo"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a device"), (stat.S_ISBLK, "a device"))


def check_target(path: Path, advice: str = "name a new file or a regular file to replace") -> None:
    """Raise UserError (ending in `advice`) unless `path` is absent or a regular file. A symbolic
    link is refused even when it points to a regular file: the rename would replace the link, not
    its file."""
    try:
        mode = path.lstat().st_mode
    except (FileNotFoundError, NotADirectoryError):
        return
    if not stat.S_ISREG(mode):
        kind = next((name for test, name in _KINDS if test(mode)), "not a regular file")
        raise UserError(f"{path} is {kind}; {advice}")


def write_atomic(path: str | Path, data: bytes | str) -> Path:
    """Write `data` to a new temporary file beside `path`, flush it to disk, then rename it over
    `path`: a crash, a full disk or a second process writing the same file never leaves half a
    file. Permissions follow the umask, as for any new file. Only a regular file is replaced
    (`check_target`)."""
    path = Path(path)
    check_target(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = _partial(path)
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
    _remove_orphans(path)
    return path


def new_folder_beside(path: Path) -> Path:
    """A new, empty, hidden folder beside `path` (umask permissions), to fill and then rename."""
    _remove_orphans(path)
    folder = _partial(path)
    folder.mkdir(parents=True)
    return folder


def _partial(path: Path) -> Path:
    """A new hidden name beside `path` for what is being written, with the writer's process id."""
    return path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.partial")


def _remove_orphans(path: Path) -> None:
    """Remove what a killed process left half-written for `path` (its process is gone); another
    process's, still writing, stays."""
    for orphan in path.parent.glob(f".{glob.escape(path.name)}.*-*.partial"):
        pid = orphan.name[len(path.name) + 2 :].partition("-")[0]
        if pid.isdigit() and not _alive(int(pid)):
            with contextlib.suppress(OSError):
                if orphan.is_dir() and not orphan.is_symlink():
                    shutil.rmtree(orphan)
                else:
                    orphan.unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process
        return True
    return True


def open_folder(out: str | Path) -> None:
    """Create the output folder `out` (and its parents) unless it is one already; UserError for an
    empty name (pass it as typed: Path("") is "."), a symbolic link on the way that leads nowhere
    or a file in the way."""
    if out == "":
        raise UserError("the output folder's name is empty; name a folder")
    out = Path(out)
    for path in (out, *out.parents):
        if kind := _broken_link(path):
            raise UserError(f"output folder {out} is {kind}; name a folder" if path == out else
                            f"output folder {out}: {path} is {kind}; name a folder")
    if out.exists() and not out.is_dir():
        raise UserError(f"output folder {out} is a file; name a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create output folder {out}: {exc.strerror}") from None


def _broken_link(path: Path) -> str | None:
    """What is wrong with `path` if it is a symbolic link that leads to no file, else None."""
    if not path.is_symlink():
        return None
    try:
        path.stat()
    except (FileNotFoundError, NotADirectoryError):
        return f"a dangling symbolic link (to {os.readlink(path)})"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symbolic link loop"
    return None
