"""Reading the files a user points handeye at: configs, sessions, import files; and writing the files a plant
reads whole (`uninterrupted`).

One rule for all of them: open regular files only (a FIFO or a device named
like a data file must never block a run, a directory must not give a
traceback), bounded in size, and -- for files named inside another file (a
manifest, a session line) -- only inside the directory that holds them.
Errors are raised as the caller's own `HandeyeError` subclass, naming the file.
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import stat
import threading
from pathlib import Path

from handeye.calib.errors import HandeyeError

#: Largest data file read whole (bytes). Sessions of a day of monitoring stay far
#: below (a sample line is ~2 kB); anything larger is not one of our files.
MAX_FILE_BYTES = 512 * 1024 * 1024

#: Linux limits of one path component and of a whole path (bytes).
NAME_MAX, PATH_MAX = 255, 4096


def read_regular_file(path, error: type[HandeyeError], *, max_bytes: int = MAX_FILE_BYTES) -> bytes:
    """The bytes of ``path`` if it is a readable regular file, else ``error`` naming it.

    Opened non-blocking, so a FIFO is refused (by ``fstat``) instead of waiting
    for a writer; symlinks to regular files are followed.
    """
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise error(f"{path}: not found") from None
    except IsADirectoryError:
        raise error(f"{path}: is a directory, expected a file") from None
    except OSError as e:
        raise error(f"{path}: cannot open ({e.strerror or e})") from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise error(f"{path}: is a directory, expected a file")
        if not stat.S_ISREG(st.st_mode):
            raise error(f"{path}: not a regular file (a FIFO, socket or device); refusing to read it")
        if st.st_size > max_bytes:
            raise error(f"{path}: {st.st_size} bytes, larger than the {max_bytes} bytes such a file can be")
        chunks, total = [], 0
        while True:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            total += len(chunk)
            if total > max_bytes:
                raise error(f"{path}: larger than the {max_bytes} bytes such a file can be")
            chunks.append(chunk)
        return b"".join(chunks)
    except OSError as e:
        if e.errno == errno.EISDIR:
            raise error(f"{path}: is a directory, expected a file") from None
        raise error(f"{path}: cannot read ({e.strerror or e})") from None
    finally:
        os.close(fd)


def read_text_file(path, error: type[HandeyeError], *, max_bytes: int = MAX_FILE_BYTES) -> str:
    """`read_regular_file` decoded as UTF-8; a file in another encoding is ``error`` naming the byte offset."""
    data = read_regular_file(path, error, max_bytes=max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise error(f"{path}: not UTF-8 text (byte {e.start}: {data[e.start:e.start + 1]!r})") from None


def inside(directory, name, error: type[HandeyeError], *, what: str) -> Path:
    """``directory / name`` if it resolves inside ``directory`` (symlinks resolved), else ``error``.

    For file names read from data files (manifests, session lines): a name
    like ``../../etc/hostname`` or an absolute path must not make handeye read
    outside the data directory.
    """
    if not isinstance(name, str) or not name or "\0" in name:
        raise error(f"{what}: expected a file name, got {name!r:.80}")
    base = Path(directory).resolve()
    try:
        target = (base / name).resolve()
    except RuntimeError:  # Python 3.11 raises this for a symlink loop
        raise error(f"{what}: {name!r:.80} is a symlink loop") from None
    # A name the OS refuses would raise OSError (ENAMETOOLONG) later, at exists() or open().
    if len(os.fsencode(target)) > PATH_MAX or any(len(os.fsencode(p)) > NAME_MAX for p in target.parts):
        raise error(f"{what}: {name!r:.80} is too long for a file name")
    if target != base and base not in target.parents:
        raise error(f"{what}: {name!r} points outside {base}; files must be inside the data directory")
    return target


@contextlib.contextmanager
def uninterrupted(signals=(signal.SIGINT, signal.SIGTERM)):
    """Hold Ctrl-C (SIGINT) and SIGTERM back while the block writes, and deliver them when it ends.

    A terminal's Ctrl-C landing inside a write (or inside the first import of
    a library the write needs, which it leaves half-initialised for the
    run's final write) would lose the file a plant reads, or give the run's
    end a traceback. The signal's handler is swapped for one that notes it,
    whichever thread the kernel hands the signal to; the block ends, the old
    handlers come back, and each noted signal is raised again at once (a
    KeyboardInterrupt right after the block). In another thread than the
    main one (where handlers cannot be set) the block runs as it is.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held = []
    previous = {s: signal.signal(s, lambda signum, frame: held.append(signum)) for s in signals}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for signum in dict.fromkeys(held):
            signal.raise_signal(signum)
