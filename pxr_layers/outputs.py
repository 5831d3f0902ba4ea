"""How output files appear: whole, together, one writer at a time, with the user's umask.

Every file pxr-layers writes is first written under a temporary name beside its final one,
``.NAME.HOST-PID.RANDOM.tmp[.EXT]``, and renamed over ``NAME`` only when complete, so a
file under its final name is always whole.

A render's outputs (its EXRs, their PNG previews, its path index) must also appear
*together*: an :class:`OutputSet` collects the completed temporaries of everything written
inside its ``with`` block and renames them all when the block ends without an error (the
path index last, so an index under its final name always has its products beside it), or
removes them all when it fails or is interrupted. Writers do not need to know about it:
:func:`write_atomically` (EXR, PNG) and the path index writer hand their finished file to
:func:`finish`, which renames at once when no set is open in this thread.

Two processes rendering into one folder (a farm retry, two artists) never interleave
their files: each commit holds an advisory lock (``flock``) on the folder (or on its
LOCK_FILE where a folder cannot be locked) while it renames, so the folder holds one
render's complete set or the other's. Ctrl-C and SIGTERM that come during the renames are
raised once they are done. Renders are identified by a
``renderId`` (see ``jobs.frame``) that ``extract`` checks between an index and its EXR.

Temporaries of processes that were killed (SIGKILL, a crash) cannot remove themselves: the
next commit into the folder removes those whose process, on this host, no longer runs.

What a final name may be (:func:`output_problem`, the one rule, checked when a file's
writing begins and again just before the renames): a new name or a regular file, never a
directory, a FIFO, a device or a socket, nor a symbolic link to one (the rename would replace
the node itself: ``-o /dev/null`` run as root would make /dev/null a regular file), and never
one of the files the running command reads (:func:`reading`: its index, the EXR it reads, its
stage, its recipe), compared as files (device and inode), so a link, a relative or a ``..``
spelling of an input is that input. Commands also call :func:`check_output` on the names they
will write before their work begins, so a mistake costs no render. :func:`confined_name_problem`
is the rule for a name that must stay inside an output folder (a recipe's productName, a
job's stem).
"""

from __future__ import annotations

import collections
import contextlib
import contextvars
import errno
import fcntl
import logging
import os
import re
import socket
import stat
import tempfile
import threading
import time
import zlib
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from . import interrupts
from .errors import OutputError
from .inputs import input_problem

log = logging.getLogger(__name__)

LOCK_TIMEOUT_SECONDS = 120.0
"""How long a commit waits for another process's commit into the same folder (a commit
only renames files: it takes milliseconds, so a lock held longer is a stuck process)."""

LOCK_FILE = ".pxr-layers.lock"
"""Locked instead of the folder itself where a folder cannot be locked (NFS emulates flock
with byte-range locks, which need a file open for writing)."""


def _process_space() -> str:
    """Who may judge whether a temporary's pid still runs: a readable host label and a hash of
    the full host name and the pid namespace (containers that share a host name, hosts whose
    first labels are equal, never take each other's pids for their own)."""
    name = socket.gethostname()
    try:
        namespace = os.stat("/proc/self/ns/pid").st_ino
    except OSError:
        namespace = 0
    label = re.sub(r"[^A-Za-z0-9]", "", name.split(".")[0])[:16] or "host"
    return f"{label}{zlib.crc32(f'{name}/{namespace}'.encode()):08x}"


_PROCESS_SPACE = _process_space()
_TEMPORARY = re.compile(r"^\..+\.(?P<space>[A-Za-z0-9]+)-(?P<pid>\d+)\.[^.]+\.tmp(\.[^.]+)?$")


def _read_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


# mkstemp creates files 0600; outputs get the mode the user's umask gives any new file.
# Read once, at import (os.umask both reads and sets, so reading it later could race with
# another thread creating a file).
FILE_MODE = 0o666 & ~_read_umask()

_current: contextvars.ContextVar[OutputSet | None] = contextvars.ContextVar("pxr_layers_output_set", default=None)
_committed: collections.Counter[Path] = collections.Counter()  # folder → files put in place
_unlockable: set[Path] = set()  # folders already warned of


FILE_SUFFIXES = frozenset({
    ".exr", ".png", ".jpg", ".jpeg", ".tif", ".tiff", ".tx", ".hdr", ".dpx", ".tga", ".bmp", ".gif", ".webp",
    ".psd", ".jp2", ".heic", ".avif", ".mov", ".mp4",  # images and movies
    ".pxlidx", ".nk", ".usd", ".usda", ".usdc", ".usdz", ".toml", ".json", ".txt", ".html",  # pxr-layers' own
})
"""Suffixes that name a file, never a folder: an ``-o`` that means "a folder" ending so is a
mistaken file name (``extract -o out/cut.png``), refused rather than made a folder called
``cut.png`` (:func:`folder_suffix_problem`). Folder names with other dots stay folders
(``renders/v1.2``, ``shot.final``)."""

_inputs: collections.Counter[tuple[int, int]] = collections.Counter()  # (st_dev, st_ino) → open `reading` blocks
_input_names: dict[tuple[int, int], str] = {}  # → the name the command was given
_inputs_lock = threading.Lock()  # the view server saves from several threads


@contextlib.contextmanager
def reading(*paths: str | os.PathLike | None) -> Iterator[None]:
    """While the block runs, refuse to write over any of ``paths``: the files the running
    command reads (an index, the EXR beside it, a stage, a recipe layer). A path that does
    not exist (a preset's name, a file the reader will report missing) or None is skipped.

    Process-wide, not per thread: a file one request of the view server reads is not
    replaced by another's save either."""
    keys = []
    for path in paths:
        if path is None:
            continue
        try:
            status = os.stat(path)
        except (OSError, ValueError):
            continue
        keys.append((status.st_dev, status.st_ino))
        with _inputs_lock:
            _inputs[keys[-1]] += 1
            _input_names.setdefault(keys[-1], os.fspath(path))
    try:
        yield
    finally:
        with _inputs_lock:
            for key in keys:
                _inputs[key] -= 1
                if _inputs[key] <= 0:
                    del _inputs[key]
                    _input_names.pop(key, None)


def output_problem(path: str | os.PathLike, what: str = "file") -> str | None:
    """Why ``path`` cannot be written as ``what`` (a noun phrase: "Nuke script", "multipart
    EXR"), or None: it is (or links to) something other than a regular file, or it is an
    input of the running command (:func:`reading`). A name that does not exist yet is fine;
    one that cannot even be looked at (too long, a loop of links) is left to the write,
    which reports it."""
    try:
        status = os.stat(path)
    except (OSError, ValueError):
        return None
    if not stat.S_ISREG(status.st_mode):
        kind = input_problem(path, what) or f"is not a regular file, not a {what}"
        through = f" (a symbolic link to {os.readlink(path)})" if os.path.islink(path) else ""
        return f"{kind}{through}: an output replaces only a regular file, so it is not written"
    with _inputs_lock:
        given = _input_names.get((status.st_dev, status.st_ino))
    if given is not None:
        other = "" if given == os.fspath(path) else f" ({given})"
        return f"is a file this command reads{other}: it is not replaced by its own output (write to another name)"
    return None


def check_output(path: str | os.PathLike, what: str = "file", suffixes: Iterable[str] | None = None) -> Path:
    """``path`` as a Path when it may be written as ``what`` (:func:`output_problem`) and,
    with ``suffixes`` (lower case, with their dot), ends with one of them; else an
    OutputError naming it."""
    path = Path(path)
    if suffixes is not None:
        allowed = tuple(suffixes)
        if not path.name.lower().endswith(allowed):
            raise OutputError(f"{path}: not a {what}'s name: a {what} ends in {' or '.join(allowed)}")
    problem = output_problem(path, what)
    if problem is not None:
        raise OutputError(f"{path}: {problem}")
    return path


def folder_suffix_problem(path: str | os.PathLike) -> str | None:
    """Why ``path``, meant as an output folder, is rather a mistaken file name (it ends with
    one of FILE_SUFFIXES and is not an existing folder), or None."""
    path = Path(path)
    if path.suffix.lower() in FILE_SUFFIXES and not path.is_dir():
        return f"names a {path.suffix} file, not a folder"
    return None


def confined_name_problem(name: str) -> str | None:
    """Why ``name`` (a file name relative to an output folder: a recipe's productName, a job's
    stem) would write outside that folder, or None: absolute, or climbing out with ``..``
    (``/`` and ``\\`` both count as separators, as on the Windows share a studio may mount).
    A subfolder (``beauty/shot.exr``) stays inside."""
    if Path(name).is_absolute() or name.startswith(("/", "\\")):
        return f"must be relative to the output folder, not absolute: {name!r}"
    if ".." in re.split(r"[/\\]", name):
        return f"must stay inside the output folder: {name!r} climbs out of it with '..'"
    return None


def committed_counts() -> dict[Path, int]:
    """Folder → how many final files this process has put in place there since
    :func:`forget_committed` (for an honest message when a command is interrupted)."""
    return dict(_committed)


def forget_committed() -> None:
    _committed.clear()


def temporary_beside(path: Path) -> tuple[int, Path]:
    """(open descriptor, path) of a new temporary file in ``path``'s folder, named so that a
    later render can tell whether the process that made it still runs. Creates the folder.
    Raises OutputError naming the folder when it cannot be created or written."""
    folder = path.parent
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder}: {input_problem(folder, 'folder') or 'is a file, not a folder'}")
    check_output(path)  # before the work of writing it
    try:
        folder.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(prefix=f".{path.stem}.{_PROCESS_SPACE}-{os.getpid()}.",
                                             suffix=".tmp" + path.suffix, dir=folder)
    except OSError as error:
        raise OutputError(f"{folder}: cannot write into this folder ({error.strerror or error})") from error
    return handle, Path(temporary)


def write_atomically(path: Path, write: Callable[[Path], None]) -> Path:
    """Call ``write(temporary_path)`` beside ``path``, then :func:`finish` it.

    A failure leaves nothing under ``path`` and removes the temporary; an OSError (a full
    disk, a read-only folder) becomes an OutputError naming ``path``. Returns where the
    file is now (its temporary while an :class:`OutputSet` holds it).
    """
    handle, temporary = temporary_beside(path)
    os.close(handle)
    try:
        write(temporary)
        if temporary.stat().st_size == 0:  # some writers report success on a full disk
            raise OSError(errno.ENOSPC, "nothing was written (is the disk full?)")
    except BaseException as error:
        temporary.unlink(missing_ok=True)
        if isinstance(error, OSError):
            raise OutputError(f"{path}: cannot write ({error.strerror or error})") from error
        raise
    return finish(temporary, path)


def finish(temporary: Path, final: Path, *, last: bool = False) -> Path:
    """A completed temporary for ``final``: held by this thread's open OutputSet (renamed
    when it commits; ``last``: after the others), else renamed now. Returns where the
    file is now."""
    outputs = _current.get()
    if outputs is not None:
        outputs.add(temporary, final, last=last)
        return temporary
    try:
        _rename_all([(temporary, final)])
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return final


class OutputSet:
    """The files written inside ``with OutputSet():`` appear together when the block ends
    normally, and none of them (not even their temporaries) when it raises or is
    interrupted."""

    def __init__(self) -> None:
        self._pending: list[tuple[Path, Path, bool]] = []  # (temporary, final, last)
        self._token: contextvars.Token | None = None

    def __enter__(self) -> OutputSet:
        self._token = _current.set(self)
        return self

    def __exit__(self, kind, error, traceback) -> None:
        _current.reset(self._token)
        if kind is None:
            self.commit()
        else:
            self.abort()

    def add(self, temporary: Path, final: Path, *, last: bool = False) -> None:
        self.discard(final)  # a file written twice in one set: the later one counts
        self._pending.append((temporary, final, last))

    def discard(self, final: Path) -> None:
        """Drop the pending file for ``final`` (e.g. an index only needed to cut layers)."""
        for temporary, path, _ in self._pending:
            if path == final:
                temporary.unlink(missing_ok=True)
        self._pending = [entry for entry in self._pending if entry[1] != final]

    def commit(self) -> None:
        ordered = sorted(self._pending, key=lambda entry: entry[2])  # stable: the `last` ones at the end
        self._pending = []
        try:
            _rename_all([(temporary, final) for temporary, final, _ in ordered])
        except BaseException:
            for temporary, _, _ in ordered:
                temporary.unlink(missing_ok=True)
            raise

    def abort(self) -> None:
        for temporary, _, _ in self._pending:
            temporary.unlink(missing_ok=True)
        self._pending = []


def _rename_all(pairs: list[tuple[Path, Path]]) -> None:
    """Rename every (temporary, final) pair holding each folder's lock, with Ctrl-C and
    SIGTERM held back until all are in place (so the set is never cut in two). Every
    temporary gets its mode first: what can fail fails before the first rename."""
    if not pairs:
        return
    folders = {final.parent.resolve() for _, final in pairs}
    with _folder_locks(folders):
        with interrupts.recorded() as received:
            for folder in folders:
                remove_stale_temporaries(folder)
            for _, final in pairs:  # again: a FIFO or a link may have appeared while the files were written
                check_output(final)
            try:
                for temporary, _ in pairs:
                    os.chmod(temporary, FILE_MODE)
            except OSError as error:
                raise OutputError(f"{temporary}: cannot set the file's mode ({error.strerror or error})") from error
            for temporary, final in pairs:
                try:
                    os.replace(temporary, final)
                except OSError as error:
                    raise OutputError(f"{final}: cannot put the file in place ({error.strerror or error})") from error
                _committed[final.parent] += 1
        interrupts.raise_recorded(received)  # once every file is in place


def remove_stale_temporaries(folder: Path) -> list[Path]:
    """Remove the temporaries in ``folder`` left by pxr-layers processes of this host that
    no longer run (killed before they could clean up). Returns what was removed."""
    removed = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        match = _TEMPORARY.match(name)
        if match and match["space"] == _PROCESS_SPACE and not _process_runs(int(match["pid"])):
            path = folder / name
            try:
                path.unlink()
            except OSError:
                continue
            removed.append(path)
    if removed:
        log.info("%s: removed %d temporary files of killed renders", folder, len(removed))
    return removed


def _process_runs(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: it runs
        return True
    return True


@contextlib.contextmanager
def _folder_locks(folders: Iterable[Path]) -> Iterator[None]:
    """Exclusive advisory locks on folders, taken in sorted order so two commits cannot
    deadlock: flock on the folder itself (no file left behind), else on its LOCK_FILE. A file
    system without locks gets one warning per folder and no lock."""
    handles: list[int] = []
    try:
        for folder in sorted(folders):
            handle = _locked(folder)
            if handle is not None:
                handles.append(handle)
        yield
    finally:
        for handle in handles:
            os.close(handle)  # closing releases the flock


def _locked(folder: Path) -> int | None:
    """An open descriptor holding ``folder``'s lock, or None where nothing can be locked."""
    for target, flags in ((folder, os.O_RDONLY), (folder / LOCK_FILE, os.O_RDWR | os.O_CREAT)):
        try:
            handle = os.open(target, flags, 0o666)
        except OSError as error:
            raise OutputError(f"{folder}: cannot open the output folder ({error.strerror or error})") from error
        try:
            if _wait_for_lock(handle, folder):
                return handle
        except BaseException:
            os.close(handle)
            raise
        os.close(handle)
    if folder not in _unlockable:
        _unlockable.add(folder)
        log.warning("%s: this file system has no locks: concurrent renders into it are not serialised", folder)
    return None


def _wait_for_lock(handle: int, folder: Path) -> bool:
    """Lock ``handle`` (waiting up to LOCK_TIMEOUT_SECONDS); False when it cannot be locked."""
    deadline = time.monotonic() + LOCK_TIMEOUT_SECONDS
    while True:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if time.monotonic() > deadline:
                raise OutputError(f"{folder}: another process has held this folder's lock for "
                                  f"{LOCK_TIMEOUT_SECONDS:.0f} s (a stuck pxr-layers?); nothing was written") from None
            time.sleep(0.02)
        except OSError as error:
            if error.errno in (errno.EBADF, errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EINVAL):
                return False
            raise OutputError(f"{folder}: cannot lock the output folder ({error.strerror})") from error
