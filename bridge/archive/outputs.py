"""Files the product writes, written so that none the user has is ever lost.

One place decides, for every command (``docs/design/archive.md``):

- an output's extension names what is written into it (``named_format``): a name that
  says Parquet never holds an archive;
- an output that is one of the command's inputs (the same file, by device and inode,
  whatever the path says) is refused, even when the user allows replacing;
- an existing file is replaced only when the user says so (``force``), and never
  while another process writes it;
- a batch output (``staged``) is written under a hidden temporary name in its own
  folder and renamed into place when complete, so a failure, Ctrl-C or full disk
  leaves no partial or empty file under the name the user asked for;
- a live archive (``create_locked``) is created exclusively, never truncating, and
  holds an exclusive ``flock`` while it is written; a second writer is refused at
  once, naming the holder's process. The kernel drops the lock when its holder dies
  (kill -9 included), so a crashed recorder's file can be repaired or replaced.
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from bridge.exceptions import OutputRefused

#: What a file of each extension the product writes holds.
FORMATS = {
    ".mcap": "an MCAP archive", ".rrd": "a Rerun recording", ".parquet": "a Parquet table",
    ".csv": "a CSV table", ".json": "a JSON file", ".yaml": "a YAML file",
    ".yml": "a YAML file", ".png": "a PNG image", ".svg": "an SVG image",
    ".pdf": "a PDF document", ".bag": "a ROS 1 bag",
}


def named_format(path: Path, *suffixes: str) -> str:
    """The extension of the output ``path``, if it is one of ``suffixes``, else refused.

    A file's extension is what the user, their tools and their file manager go by: an
    archive written under a ``.parquet`` name would be opened as a table and fail, or be
    mistaken for one and deleted. Every command's outputs go through this one rule.

    Args:
        path: The output the user named.
        suffixes: The extensions of what the command writes there (``.mcap``), each one
            of ``FORMATS``.

    Returns:
        Its extension, lower-case.

    Raises:
        OutputRefused: Its extension is none of them; the message names those that are.
    """
    suffix = path.suffix.lower()
    if suffix in suffixes:
        return suffix
    kinds = list(dict.fromkeys(FORMATS[s] for s in suffixes))
    raise OutputRefused(f"{path}: this writes {_either(kinds)}; name the file "
                        f"{_either(list(suffixes))}")


def named_folder(path: Path) -> Path:
    """``path`` as a folder for a run's files, refused if its extension names a file.

    Args:
        path: The folder the user named.

    Returns:
        ``path``.

    Raises:
        OutputRefused: Its extension is one a file the product writes has (``.mcap``).
    """
    if path.suffix.lower() in FORMATS:
        raise OutputRefused(f"{path}: this writes a folder of files, and {path.suffix} "
                            "names a file; give a folder name without it")
    return path


def _either(words: Sequence[str]) -> str:
    """``a``, ``a or b``, ``a, b or c``."""
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} or {words[-1]}"


def lock_holder(path: Path) -> int | None:
    """The process writing ``path`` (0 when it cannot be named), or None if none is."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NONBLOCK)  # a FIFO: no wait
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _flock_pid(os.fstat(fd).st_ino)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _flock_pid(inode: int) -> int:
    """The holder of a write flock on ``inode``, from Linux's /proc/locks (0: unknown)."""
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return 0
    for line in lines:
        fields = line.split()
        # "1: FLOCK  ADVISORY  WRITE 1234 fe:00:9977968 0 EOF"
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[3] == "WRITE" \
                and fields[5].rsplit(":", 1)[-1] == str(inode):
            return int(fields[4])
    return 0


def refuse_if_written(path: Path) -> None:
    """Refuse ``path`` while another process writes it (holds its lock)."""
    holder = lock_holder(path)
    if holder is not None:
        who = f"process {holder}" if holder else "another process"
        raise OutputRefused(f"{path} is being written by {who}; stop it first, or choose "
                            "another name")


def refuse(path: Path, inputs: Iterable[Path] = (), force: bool = False) -> None:
    """Refuse ``path`` as an output unless writing it destroys nothing the user did not give up.

    Its folder must exist; it must not be a folder, one of ``inputs``, or a file another
    process is writing; an existing file only with ``force``.
    """
    folder = path.parent
    if not folder.is_dir():
        raise OutputRefused(f"{path}: the folder {folder} does not exist; create it or "
                            "choose another path")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputRefused(f"{path}: no permission to write in {folder}; choose another "
                            "folder")
    try:
        st = path.stat()
    except FileNotFoundError:
        if path.is_symlink():
            raise OutputRefused(f"{path} is a link to a missing file; remove it or choose "
                                "another path") from None
        return
    if stat.S_ISDIR(st.st_mode):
        raise OutputRefused(f"{path} is a folder; give a file name")
    if not stat.S_ISREG(st.st_mode):  # a device or pipe would be replaced by a file
        raise OutputRefused(f"{path} is not a regular file; give a file name")
    for given in inputs:
        try:
            same = os.path.samestat(st, Path(given).stat())
        except OSError:
            continue
        if same:
            raise OutputRefused(f"{path} is the input {given}; write to another file")
    refuse_if_written(path)
    if not force:
        raise OutputRefused(f"{path} exists; choose another name, or --force to replace it")


def create_locked(path: Path, force: bool = False) -> IO[bytes]:
    """A new file at ``path`` to write, created exclusively and holding an exclusive lock.

    The lock holds until the file is closed. An existing file is refused (replaced with
    ``force`` unless another process writes it). Other OS errors (no permission, full
    disk) raise as OSError.
    """
    if force:
        refuse(path, force=True)
        path.unlink(missing_ok=True)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
    except FileExistsError:
        refuse(path)
        raise OutputRefused(f"{path} appeared while it was being created; try again") \
            from None
    except FileNotFoundError:
        refuse(path)  # names the missing folder
        raise
    # a new file of ours: only a passing lock_holder probe can hold it, so wait it out
    fcntl.flock(fd, fcntl.LOCK_EX)
    return os.fdopen(fd, "wb")


def temporary(path: Path) -> Path:
    """The hidden name ``staged`` writes ``path`` under.

    Same folder (the rename stays on one file system) and same suffix (writers that
    pick a format by it still do).
    """
    return path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")


@contextmanager
def staged(path: Path, inputs: Iterable[Path] = (), force: bool = False) -> Iterator[Path]:
    """The temporary file to write the batch output ``path`` into.

    Refused at once as ``refuse`` says; renamed to ``path`` when the block ends, removed
    if it raises (Ctrl-C included).
    """
    refuse(path, inputs, force)
    temp = temporary(path)
    try:
        yield temp
        _commit(temp, path, force)
    finally:
        temp.unlink(missing_ok=True)


def _commit(temp: Path, path: Path, force: bool) -> None:
    """Put ``temp`` in place of ``path``.

    Without ``force``, never over a file that appeared meanwhile (a hard link fails if
    the name exists; rename would not).
    """
    if force:
        os.replace(temp, path)
        return
    try:
        os.link(temp, path)
    except FileExistsError:
        raise OutputRefused(f"{path} appeared while it was being written; the output "
                            "was not kept, run again with another name") from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV):
            raise
        refuse(path)  # a file system without hard links: check, then rename
        os.replace(temp, path)


def free_folder(path: Path, force: bool = False, next_free: bool = False) -> Path:
    """A folder for a run's results that holds no earlier run's.

    ``path`` if it is missing or empty, or with ``force``; else, with ``next_free``, the
    first missing or empty one of path-2, path-3, ...; else refused.
    """
    def empty(folder: Path) -> bool:
        return not folder.exists() or (folder.is_dir() and not any(folder.iterdir()))

    if path.exists() and not path.is_dir():
        raise OutputRefused(f"{path} is a file, not a folder; choose another path")
    if force or empty(path):
        return path
    if next_free:
        n = 2
        while not empty(path.with_name(f"{path.name}-{n}")):
            n += 1
        return path.with_name(f"{path.name}-{n}")
    raise OutputRefused(f"{path} holds an earlier run's files; choose another folder, or "
                        "--force to replace them")
