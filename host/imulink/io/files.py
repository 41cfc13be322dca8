"""The user's files: inputs read only when they are regular files of a bounded size, and
outputs that never destroy what was there unless the job succeeded.

- :func:`check_regular_file` / :func:`read_regular_file`: a FIFO or a device (/dev/zero)
  would block or never end, and a huge file would exhaust memory, so only regular files
  up to a size are read.
- :func:`create_beside`: a new file next to a target, created exclusively (never an
  existing file truncated), for output that takes the target's name only when complete.
- :func:`publish`: give such a file its final name, replacing an existing file only when
  asked.
- :func:`check_output` / :func:`write_replacing`: write an export (CSV, .npz) under a
  temporary name and rename it at the end, refusing to write over the inputs of the job.
"""
from __future__ import annotations

import os
import secrets
import stat
from pathlib import Path

from imulink.errors import ImulinkError


class FileError(ImulinkError):
    """A file that cannot be read or written as asked; the message names it and why."""


def _describe(exc: OSError) -> str:
    return exc.strerror or str(exc)


def check_regular_file(path, max_bytes: int) -> None:
    """FileError unless `path` is a regular file of at most `max_bytes`."""
    path = Path(path)
    try:
        info = path.stat()
    except OSError as exc:
        raise FileError(f"cannot read {path}: {_describe(exc)}") from None
    if not stat.S_ISREG(info.st_mode):
        raise FileError(f"{path} is not a regular file (a directory, FIFO or device cannot be read as one)")
    if info.st_size > max_bytes:
        raise FileError(f"{path} is {info.st_size} bytes, more than the {max_bytes} this command reads")


def read_regular_file(path, max_bytes: int) -> bytes:
    """The bytes of `path` (see :func:`check_regular_file`)."""
    check_regular_file(path, max_bytes)
    try:
        with open(path, "rb") as f:
            return f.read(max_bytes + 1)
    except OSError as exc:
        raise FileError(f"cannot read {path}: {_describe(exc)}") from None


def check_writable_target(path, replace: bool) -> None:
    """FileError unless `path` may become a regular file: it does not exist, or it is one
    and `replace` is set. A device or a directory is never replaced (a rename onto
    /dev/null would remove the device node)."""
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        return
    except OSError as exc:
        raise FileError(f"cannot write {path}: {_describe(exc)}") from None
    if not stat.S_ISREG(info.st_mode):
        raise FileError(f"{path} exists and is not a regular file")
    if not replace:
        raise FileError(f"{path} exists; it is left as it is (--force replaces it)")


def create_beside(target) -> tuple[int, Path]:
    """A new, empty file in `target`'s directory (a rename to `target` is then atomic),
    open for appending, with the permissions the umask gives a new file. Returns its file
    descriptor and path."""
    target = Path(target)
    while True:
        candidate = target.with_name(f".{target.stem}.{secrets.token_hex(4)}.partial{target.suffix}")
        try:
            return os.open(candidate, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_EXCL, 0o666), candidate
        except FileExistsError:
            continue  # another job's temporary file: draw another name
        except OSError as exc:
            raise FileError(f"cannot create a file in {target.parent}: {_describe(exc)}") from None


def publish(temporary: Path, target: Path, replace: bool) -> None:
    """Give `temporary` the name `target`. Without `replace`, a `target` that exists by now
    is left alone: FileError, and `temporary` keeps its name."""
    if replace:
        os.replace(temporary, target)
        return
    try:
        os.link(temporary, target)  # fails if target exists: no moment in which a file could be overwritten
    except FileExistsError:
        raise FileError(f"{target} was created meanwhile by another program; it is left as it is") from None
    except OSError:  # a file system without hard links (FAT): check, then rename
        if target.exists():
            raise FileError(f"{target} was created meanwhile by another program; it is left as it is") from None
        os.rename(temporary, target)
        return
    os.unlink(temporary)


def same_file(a, b) -> bool:
    """Whether two paths name the same existing file (links and '..' included)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_output(target, inputs=()) -> None:
    """FileError when `target` is one of `inputs`, or exists and is not a regular file."""
    if any(same_file(target, source) for source in inputs):
        raise FileError(f"{target} is an input of this command; it is not written over (give another output file)")
    check_writable_target(target, replace=True)


def write_replacing(target, write, inputs=()) -> None:
    """Run `write(path)` on a temporary file beside `target`, then rename it to `target`.

    A failure (a full disk, an exception in `write`) leaves `target` as it was and no
    temporary file behind. Refuses (FileError) what :func:`check_output` refuses.
    """
    target = Path(target)
    check_output(target, inputs)
    fd, temporary = create_beside(target)
    os.close(fd)
    try:
        write(temporary)
        os.replace(temporary, target)
    except OSError as exc:
        raise FileError(f"cannot write {target}: {_describe(exc)}") from None
    finally:
        temporary.unlink(missing_ok=True)  # gone already after the rename
