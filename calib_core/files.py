"""Files read and written safely.

Written whole: a reader sees the old file or the new one, never half of one, and the file gets the mode
any other file of the user's would (0666 less the umask), so a driver or viewer run as another user can
read it. Read bounded: a file a user names is a regular file of at most a stated size, so naming a FIFO
(which blocks) or /dev/zero (which never ends) is refused, not waited on.
"""

from __future__ import annotations

import os
import re
import stat
import tempfile
from pathlib import Path

from .errors import InputError


def write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~umask())  # mkstemp makes 0600 whatever the umask
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def umask() -> int:
    """The process's umask, read without changing it (Linux reports it in /proc; elsewhere it is set and
    set back at once)."""
    try:
        found = re.search(r"^Umask:\s*([0-7]+)", Path("/proc/self/status").read_text(), re.MULTILINE)
    except OSError:
        found = None
    if found:
        return int(found.group(1), 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def read_regular_file(path: str | Path, max_bytes: int, what: str = "file") -> bytes:
    """The bytes of `path`, a regular file of at most `max_bytes`; InputError naming the file otherwise.
    Opened without blocking and checked before it is read: a FIFO, a device, a directory or a file that
    grew past the bound while read is refused."""
    name = str(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise InputError(f"{what} does not exist", file=name) from None
    except OSError as exc:
        raise InputError(f"cannot read the {what} ({exc.strerror or exc.__class__.__name__})", file=name) from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            kind = "a directory" if stat.S_ISDIR(info.st_mode) else "not a regular file (a pipe, a device?)"
            raise InputError(f"the {what} is {kind}", file=name)
        if info.st_size > max_bytes:
            raise InputError(f"the {what} is larger than {_size(max_bytes)} ({_size(info.st_size)})", file=name)
        with os.fdopen(fd, "rb", closefd=False) as fh:
            data = fh.read(max_bytes + 1)
    except OSError as exc:
        raise InputError(f"cannot read the {what} ({exc.strerror or exc.__class__.__name__})", file=name) from None
    finally:
        os.close(fd)
    if len(data) > max_bytes:
        raise InputError(f"the {what} is larger than {_size(max_bytes)}", file=name)
    return data


def read_text_file(path: str | Path, max_bytes: int, what: str = "file") -> str:
    """read_regular_file, as UTF-8 text (a byte-order mark dropped)."""
    try:
        return read_regular_file(path, max_bytes, what).decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(f"the {what} is not UTF-8 text", file=str(path)) from None


def _size(n: int) -> str:
    return f"{n / (1024 * 1024):.1f} MB" if n >= 1024 * 1024 else f"{n / 1024:.0f} kB"
