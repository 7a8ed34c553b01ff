"""Reading a file a user named, without hanging on it or filling memory with it.

A path given on the command line or in a configuration can name anything: a
named pipe (which blocks a reader until someone writes), a device such as
``/dev/zero`` (endless) or ``/dev/watchdog`` (opening it arms a timer), a
folder, or a regular file far larger than anything the program reads.
:func:`read_regular_file` reads only regular files up to a stated size,
checking the kind before opening (so no device is ever opened) and again on
the open descriptor (so a file swapped in between is caught too).
"""

from __future__ import annotations

import os
import stat

__all__ = ["FileRefused", "read_regular_file", "describe_kind"]


class FileRefused(ValueError):
    """The path is not a readable regular file within the size allowed.

    The message says why, without the path (the caller names it).
    """


def describe_kind(mode: int) -> str:
    """What a non-regular file is, in words: 'a folder', 'a named pipe (FIFO)'..."""
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a named pipe (FIFO)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _check(st: os.stat_result, max_bytes: int) -> None:
    if not stat.S_ISREG(st.st_mode):
        kind = describe_kind(st.st_mode)
        raise FileRefused(kind if kind.startswith("not ") else f"{kind}, not a regular file")
    if st.st_size > max_bytes:
        raise FileRefused(f"{st.st_size:,} bytes, more than the {max_bytes:,} allowed")


def read_regular_file(path: str | os.PathLike, max_bytes: int) -> bytes:
    """The whole content of a regular file of at most ``max_bytes`` bytes.

    Raises :class:`FileRefused` for a missing or unreadable path, anything
    but a regular file, or a file larger than ``max_bytes``.
    """
    try:
        _check(os.stat(path), max_bytes)
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except FileNotFoundError:
        raise FileRefused("no such file") from None
    except OSError as exc:
        raise FileRefused(f"cannot read ({exc.strerror or exc})") from None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fd)
        _check(st, max_bytes)
        # read(n) allocates n bytes at once: ask for what the file holds, then in
        # bounded chunks should it have grown
        limit = max_bytes + 1
        chunks: list[bytes] = []
        total = 0
        want = min(st.st_size + 1, limit)
        try:
            while total < limit:
                asked = min(want, limit - total)
                chunk = fh.read(asked)
                chunks.append(chunk)
                total += len(chunk)
                if len(chunk) < asked:      # end of file
                    break
                want = 1 << 20
        except OSError as exc:
            raise FileRefused(f"cannot read ({exc.strerror or exc})") from None
        data = b"".join(chunks)
    if len(data) > max_bytes:
        raise FileRefused(f"more than the {max_bytes:,} bytes allowed (the file is growing)")
    return data
