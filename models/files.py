"""Writing files safely: atomically, as a whole set, never outside the output folder, never
replacing a user's file unasked.

The one home of this mechanism.  Single files (parameter sets, logs, sweep chunks) are written
through :func:`atomic_write_text`, :func:`atomic_write_bytes` or :func:`atomic_path` (a temporary
file, then a rename).  A command's whole output set goes through :func:`output_set`::

    check_output_dir(out)                       # before any work: one line if --out cannot be a folder
    with output_set(out, ["metrics.csv", "report.md"], force=False) as w:
        ...                                     # the work
        w.write_text("metrics.csv", text)       # or w.path("plot.png") for writers that need a name

which

- checks the location first: ``out`` an existing file, a parent that is a file, a folder that
  cannot be created or written: one-line :class:`ConfigError` naming ``--out`` (exit 2);
- takes a lock on ``out`` (``out/.mitigate.lock``, ``fcntl.flock``, removed when done; a lock of a
  killed process is released by the kernel, even after ``kill -9``): a second command into the same
  folder is refused at once with the first one's process id, so two runs never mix their files;
- refuses names that exist unless ``force`` (or unless a previous run was killed while committing
  them, below), and names that would leave ``out`` (absolute, ``..``);
- writes every file into a staging folder inside ``out`` (``.mitigate-staging-<pid>``) and moves
  them into place only when the work succeeded: a run killed while working or writing leaves
  ``out`` as it was (the next run removes the stale staging folder);
- marks the few milliseconds of moving with ``out/.mitigate-incomplete.json`` (the names being
  moved): a run killed then leaves that marker, and the next run says so and replaces those files
  without ``--force``; names declared but not written this time are removed then (no file of an
  older run stays mixed in).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
from pathlib import Path, PurePath
from typing import Iterable, Iterator

from models.errors import ConfigError, quote

__all__ = ["atomic_write_text", "atomic_write_bytes", "atomic_path", "refuse_overwrite", "check_output_dir",
           "check_output_file", "output_set", "OutputSet", "file_stem", "LOCK_NAME", "MARKER_NAME"]

LOCK_NAME = ".mitigate.lock"
MARKER_NAME = ".mitigate-incomplete.json"
STAGING_PREFIX = ".mitigate-staging-"


def refuse_overwrite(path: str | os.PathLike, overwrite: bool, arg: str = "overwrite") -> Path:
    """``Path(path)``; a ConfigError if it exists and ``overwrite`` is False (the message names
    the caller's argument ``arg``; the CLI translates it to its ``--force`` flag)."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise ConfigError(f"{path}: file exists; refusing to overwrite (pass {arg}=True)")
    return path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, overwrite: bool = False):
    """Yield a temporary path next to ``path``; on success rename it onto ``path``, on error
    delete it.  Writers that need a file name (matplotlib, numpy) write to the yielded path."""
    path = refuse_overwrite(path, overwrite)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def atomic_write_text(path: str | os.PathLike, text: str, *, overwrite: bool = False, durable: bool = False) -> Path:
    """Write ``text`` to ``path`` atomically; refuse to replace a file unless ``overwrite``.

    ``durable``: flush the data to disk before the rename (a file that survives a crash or a
    ``kill -9`` whole or not at all, e.g. a sweep's chunks)."""
    with atomic_path(path, overwrite=overwrite) as tmp:
        with open(tmp, "w", newline="") as fh:
            fh.write(text)
            if durable:
                fh.flush()
                os.fsync(fh.fileno())
    return Path(path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, overwrite: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically; refuse to replace a file unless ``overwrite``."""
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)
    return Path(path)


# ----------------------------------------------------------------------------- output sets
def file_stem(name: str, where: str) -> str:
    """``name`` if it can be a file name inside an output folder (one path component, no ``/``,
    ``\\``, NUL, not ``.`` or ``..``, at most 200 characters), else a one-line ConfigError naming
    ``where`` (e.g. a scenario ``name`` used for ``<name>.csv``)."""
    if not isinstance(name, str) or not name.strip() or name.strip() in (".", "..") or len(name) > 200 \
            or any(c in name for c in "/\\\0") or any(ord(c) < 32 for c in name):
        raise ConfigError(f"{where} must be usable as a file name (no '/', '\\', control characters, not '.' "
                          f"or '..', at most 200 characters), got {quote(name)}")
    return name


def _first_existing(path: Path) -> Path:
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def check_output_dir(out: str | os.PathLike, what: str = "--out") -> Path:
    """``Path(out)`` if it is, or can become, a writable folder; else one ConfigError naming ``what``
    (empty, an existing file, a parent that is a file, a folder that is not writable).  Creates nothing."""
    if isinstance(out, str) and not out.strip():
        raise ConfigError(f"{what} must name a folder, got an empty string")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{what} {out} is a file, expected a folder (choose another {what})")
    base = _first_existing(out.absolute())
    if not base.is_dir():
        raise ConfigError(f"{what} {out}: cannot create the folder: {base} is a file, not a folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise ConfigError(f"{what} {out}: {base} is not writable (permission denied or a read-only file system)")
    return out


def check_output_file(path: str | os.PathLike, force: bool, what: str = "--out") -> Path:
    """``Path(path)`` if a file can be written there: not a folder, its folder creatable and
    writable, not existing unless ``force`` (one-line ConfigError naming ``what`` otherwise)."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{what} {path} is a folder, expected a file name")
    if len(os.fsencode(path.name)) > 255 or not path.name:
        raise ConfigError(f"{what} {path}: not a usable file name (empty, or longer than 255 bytes)")
    check_output_dir(path.parent if str(path.parent) else Path("."), what)
    if path.exists() and not force:
        raise ConfigError(f"{what} {path}: file exists; refusing to overwrite (pass force=True)")
    return path


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _relative(name: str, out: Path) -> PurePath:
    rel = PurePath(name)
    if rel.is_absolute() or not rel.parts or any(p in ("..", "") for p in rel.parts) or "\0" in name:
        raise ConfigError(f"{out}: output name {name!r} would be written outside the folder; refusing")
    return rel


class OutputSet:
    """The output set being written (:func:`output_set`): ``root`` is the final folder, ``dir``
    the staging folder the files go to until the set is committed."""

    def __init__(self, root: Path, staging: Path, names: tuple[str, ...]):
        self.root, self.dir, self.names = root, staging, names
        self.notes: list[str] = []

    def path(self, name: str) -> Path:
        """Where to write ``name`` (a path relative to the set) now; it lands in ``root/name``."""
        p = self.dir / _relative(name, self.root)
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def final(self, name: str) -> Path:
        """Where ``name`` will be once the set is committed."""
        return self.root / _relative(name, self.root)

    def write_text(self, name: str, text: str) -> Path:
        with open(self.path(name), "w", newline="") as fh:
            fh.write(text)
        return self.final(name)

    def write_bytes(self, name: str, data: bytes) -> Path:
        self.path(name).write_bytes(data)
        return self.final(name)

    def staged(self) -> list[str]:
        """Names written so far (relative, ``/``-separated)."""
        if not self.dir.exists():
            return []
        return sorted(p.relative_to(self.dir).as_posix() for p in self.dir.rglob("*") if p.is_file())


def _lock(out: Path):
    """An exclusive, non-blocking ``flock`` on ``out/.mitigate.lock`` (holding this process's id);
    ConfigError naming the holder if another process has it.  The file is removed again by
    :func:`_unlock`; a lock taken on a file another process unlinked meanwhile is retaken."""
    import fcntl
    lock = out / LOCK_NAME
    for _ in range(20):
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                os.close(fd)
                raise
            try:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            except OSError:
                holder = "?"
            os.close(fd)
            raise ConfigError(f"--out {out} is in use by another mitigate command (process {holder}); wait for it "
                              f"to finish or choose another --out") from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.pwrite(fd, str(os.getpid()).encode(), 0)
            return fd, lock
        os.close(fd)            # the holder removed that file as we took it: take the new one
    raise ConfigError(f"--out {out}: could not take its lock (it keeps changing); try again")


def _unlock(held) -> None:
    """Remove the lock file (while still holding it), then release it."""
    fd, lock = held
    try:
        with contextlib.suppress(OSError):
            lock.unlink()
    finally:
        os.close(fd)


def _clean_stale(out: Path) -> list[str]:
    """Remove staging folders of dead processes; the names a killed commit left incomplete."""
    for d in out.glob(f"{STAGING_PREFIX}*"):
        pid = d.name[len(STAGING_PREFIX):]
        if d.is_dir() and not (pid.isdigit() and int(pid) != os.getpid() and _pid_alive(int(pid))):
            shutil.rmtree(d, ignore_errors=True)
    marker = out / MARKER_NAME
    if not marker.exists():
        return []
    try:
        names = json.loads(marker.read_text()).get("names", [])
        return [n for n in names if isinstance(n, str)]
    except (OSError, ValueError, AttributeError):
        return []


@contextlib.contextmanager
def output_set(out: str | os.PathLike, names: Iterable[str], *, force: bool = False, lock: bool = True,
               arg: str = "force") -> Iterator[OutputSet]:
    """Write a whole output set into the folder ``out`` (module docstring).

    Parameters
    ----------
    out : the output folder (created if missing)
    names : every file the set may write, relative to ``out`` (checked for existing files now)
    force : replace existing files of those names
    lock : hold ``out``'s lock for the whole block (a second command into ``out`` is refused);
        False for a command that writes single files into a folder others share (``identify``)
    arg : the caller's name of ``force`` in messages

    Raises
    ------
    ConfigError : ``out`` is not a usable folder, is in use, or holds one of ``names`` without
        ``force`` -- all before the block runs.
    """
    out = check_output_dir(out)
    names = tuple(_relative(n, out).as_posix() for n in names)
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd = _lock(out) if lock else None
    except OSError as exc:
        raise ConfigError(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    staging = out / f"{STAGING_PREFIX}{os.getpid()}"
    committed = False
    try:
        incomplete = set(_clean_stale(out)) if lock else set()
        w = OutputSet(out, staging, names)
        if incomplete:
            w.notes.append(f"{out}: replacing an output set left incomplete by a killed run "
                           f"({len(incomplete)} file(s))")
        existing = [n for n in names if (out / n).exists() and n not in incomplete]
        if existing and not force:
            more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
            raise ConfigError(f"{out / existing[0]}: file exists{more}; refusing to overwrite (pass {arg}=True)")
        staging.mkdir(exist_ok=True)
        yield w
        _commit(w, set(names) | incomplete)
        committed = True
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        if fd is not None:
            _unlock(fd)
        if created and not committed:
            with contextlib.suppress(OSError):
                out.rmdir()           # only if empty: nothing of ours is left


def _commit(w: OutputSet, declared: set[str]) -> None:
    """Move the staged files into place under the incomplete-marker (module docstring)."""
    staged = w.staged()
    gone = sorted(n for n in declared - set(staged) if (w.root / n).exists())
    marker = w.root / MARKER_NAME
    atomic_write_text(marker, json.dumps({"pid": os.getpid(), "names": sorted(set(staged) | set(gone))}) + "\n",
                      overwrite=True, durable=True)
    for n in staged:
        dst = w.root / n
        dst.parent.mkdir(parents=True, exist_ok=True)
        os.replace(w.dir / n, dst)
    for n in gone:
        with contextlib.suppress(OSError):
            (w.root / n).unlink()
    with contextlib.suppress(OSError):
        dfd = os.open(w.root, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    marker.unlink()
