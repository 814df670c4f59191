"""Output folders that always hold one complete result or none.

A run reserves its folder before any work (:func:`reserve`): the path is
checked (every existing part a folder, the nearest existing one writable,
names short enough, not the working folder or one of its parents, and an
existing folder holding only files skelfem writes), and a lock file
``.<name>.lock`` beside it is taken with ``flock``, so a second run into
the same folder is refused at once (the kernel drops the lock when a process
dies, however it dies). Stale staging folders of earlier runs that were
killed are removed then.

The run writes into a fresh staging folder ``.<name>.tmp-<pid>-<random>``
beside the target (:func:`publish`) and, once every file is complete,
exchanges it with the target in one ``renameat2(RENAME_EXCHANGE)`` (two
renames where the file system lacks it) and removes the old content. Files
that another command wrote into the same folder (``simulate``'s result
beside ``ik``'s, say) are carried over unchanged by hard links. A run that
fails or is interrupted removes its staging folder, the lock and any parent
folders it created, so nothing is left behind.

Under MPI only rank 0 touches the file system; the verdict of each step is
broadcast, so every rank raises the same :class:`OutputError` together.
"""
from __future__ import annotations

import ctypes
import errno
import fcntl
import os
import re
import secrets
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from ..runtime import interrupts

# files each command writes; a folder holding only these (and stale temporaries) may be replaced
OUTPUTS = {
    "simulate": ("result.json", "solution.xdmf", "solution.h5", "deformed.png",
                 "trajectory.csv", "trajectory.xdmf", "trajectory.h5", "motion.gif", "stages.xdmf", "stages.h5"),
    "ik": ("ik.json", "ik.png"),
    "track": ("track.csv", "track.json", "track.png"),
    "bench": ("bench.json",),
    "sweep": ("summary.csv", "summary.png"),
    "fabricate": ("fabrication.json", "fabrication.png", "casting.png"),
    "optimize": ("optimize.json", "schedules.csv", "optimize.png"),
    "optimize-design": ("optimize_design.json", "optimized.toml", "history.csv"),
    "calibrate": ("calibration.json", "calibrated.toml", "partial.toml", "fit.csv", "fit.png", "residuals.png",
                  "parameters.png"),
}
# files whose names follow the design (one per bone): a pattern per command
PATTERNS = {"fabricate": re.compile(r"^((bone_[^/\\]+|mould_(bottom|top))\.(stl|step)|[^/\\]+\.3mf)$"),
            "simulate": re.compile(r"^deformed-[^/\\]+\.png$")}          # one picture per stage
STALE_FILE = re.compile(r"^\.(result|solution|deformed|trajectory|motion|stages|optimize|schedules|calibration"
                        r"|calibrated|partial|fit|residuals|parameters|ik|track|bench|summary|fabrication|casting"
                        r"|optimize_design|optimized|history)-.*")
NAME_MAX = 255
RESERVED_CHARS = 48           # room for ".<name>.tmp-<pid>-<random>" beside the target
PATH_MAX = 4096 - 128


def written_by(name: str) -> str | None:
    """The command that writes a file of this name (None if none does)."""
    for kind, names in OUTPUTS.items():
        if name in names:
            return kind
    for kind, pattern in PATTERNS.items():
        if pattern.match(name):
            return kind
    return None


class OutputError(Exception):
    """The output folder cannot be used; one line for the user (exit 1)."""


def check_name(name: str, what: str = "name", max_len: int = 100) -> str | None:
    """Why name cannot be a folder name of its own (None if it can)."""
    if not isinstance(name, str) or not name:
        return f"{what} must be a non-empty name"
    if any(0xD800 <= ord(c) <= 0xDFFF for c in name):
        return f"{what} must be valid UTF-8 text (it holds a byte that is not)"
    bad = [c for c in name if c in "/\\" or ord(c) < 32 or ord(c) == 127]
    if bad:
        return f"{what} must not contain {bad[0]!r}"
    if name in (".", ".."):
        return f"{what} {name!r} is not a folder name"
    if name.startswith("."):
        return f"{what} must not start with '.' (hidden names are skelfem's temporaries)"
    if len(name.encode("utf-8", "surrogatepass")) > max_len:
        return f"{what} is longer than {max_len} bytes"
    if name != name.strip():
        return f"{what} must not start or end with white space"
    return None


# -- checking a path, without writing anything -------------------------------------------------------
def _foreign(folder: Path, kind: str) -> str | None:
    """The first entry of an existing folder that skelfem did not write (None if all are ours)."""
    try:
        entries = sorted(os.listdir(folder))
    except OSError as exc:
        return f"({exc.strerror})"
    for e in entries:
        if written_by(e) is not None or STALE_FILE.match(e):
            continue
        path = folder / e
        if kind == "sweep":
            if e.startswith(".") and re.match(r"^\..*\.(lock|tmp-.*|old-.*)$", e):
                continue                      # a case's lock or staging folder
            if path.is_dir() and not path.is_symlink() and not e.startswith("."):
                inner = _foreign(path, "case")
                if inner is None:
                    continue
                return f"{e}/{inner}"
        return e
    return None


def check_path(out, kind: str = "simulate") -> Path:
    """The real path of output folder out, or OutputError saying why it cannot be one."""
    shown = str(out) if len(str(out)) <= 200 else str(out)[:120] + "..." + str(out)[-60:]
    try:
        out = Path(out)
        if not str(out) or "\0" in str(out):
            raise OutputError(f"{shown!r}: not a folder name")
        target = Path(os.path.realpath(out))
    except (OSError, ValueError) as exc:
        raise OutputError(f"{shown}: not a usable path ({exc})") from None
    if len(os.fsencode(str(target))) > PATH_MAX:
        raise OutputError(f"{shown}: path too long ({len(os.fsencode(str(target)))} bytes)")
    for part in target.parts[1:]:
        if len(os.fsencode(part)) > NAME_MAX - RESERVED_CHARS:
            raise OutputError(f"{shown}: the name {part[:40]!r}... is too long for a folder "
                              f"(at most {NAME_MAX - RESERVED_CHARS} bytes)")
    cwd = Path(os.path.realpath(os.getcwd()))
    if target == cwd or target in cwd.parents or target.parent == target:
        raise OutputError(f"{shown}: is the working folder or one of its parents; name a folder for the results")
    # every existing part must be a folder; the nearest existing one writable
    probe = target
    while not os.path.lexists(probe):
        probe = probe.parent
    if not probe.is_dir():
        what = "output path" if probe == target else f"{probe}"
        raise OutputError(f"{shown}: {what} exists and is not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"{shown}: cannot create it: {probe} is not writable")
    if probe == target:
        bad = _foreign(target, kind)
        if bad is not None:
            raise OutputError(f"{shown}: the folder holds {bad!r}, which skelfem did not write; "
                              "choose another --out or empty it (a run replaces the folder's results)")
    return target


# -- locks -----------------------------------------------------------------------------------------
_HELD: dict = {}        # real target path -> Reservation (rank 0 of this process)
ON_COMMIT = None        # called once a result is committed (the CLI: interrupts.finish for one-result commands)


class Reservation:
    """A locked output folder (rank 0's side); see reserve()."""

    def __init__(self, target: Path, kind: str):
        self.target, self.kind = target, kind
        self.lock_path = target.parent / f".{target.name}.lock"
        self.fd: int | None = None
        self.created: list[Path] = []     # parent folders this run made

    def acquire(self, shown: str) -> None:
        parent = self.target.parent
        missing = []
        p = parent
        while not p.exists():
            missing.append(p)
            p = p.parent
        try:
            for d in reversed(missing):
                d.mkdir()
                self.created.append(d)
        except OSError as exc:
            self._remove_created()
            raise OutputError(f"{shown}: cannot create {d}: {exc.strerror}") from None
        while True:
            try:
                fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            except OSError as exc:
                self._remove_created()
                raise OutputError(f"{shown}: cannot write beside it ({exc.strerror})") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                try:
                    holder = os.pread(fd, 64, 0).decode(errors="replace").strip()
                except OSError:
                    holder = ""
                os.close(fd)
                self._remove_created()
                raise OutputError(f"{shown}: another skelfem run{' (pid ' + holder + ')' if holder else ''} "
                                  "is writing this folder; wait for it or choose another --out") from None
            try:
                same = os.fstat(fd).st_ino == os.stat(self.lock_path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)                      # the file was removed by its last owner meanwhile: retry
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        self.fd = fd
        self.clean_stale()

    def clean_stale(self) -> None:
        """Staging and old folders of runs that died (we hold the lock: nobody else writes here)."""
        prefix = (f".{self.target.name}.tmp-", f".{self.target.name}.old-")
        try:
            for e in os.listdir(self.target.parent):
                if e.startswith(prefix):
                    _remove(self.target.parent / e)
        except OSError:
            pass
        if self.target.is_dir():
            try:
                for e in os.listdir(self.target):
                    if STALE_FILE.match(e):
                        _remove(self.target / e)
            except OSError:
                pass

    def release(self, keep_parents: bool = False) -> None:
        with interrupts.critical():
            if self.fd is not None:
                try:
                    os.unlink(self.lock_path)
                except OSError:
                    pass
                os.close(self.fd)
                self.fd = None
            if not keep_parents:
                self._remove_created()
            self.created = []
            _HELD.pop(self.target, None)

    def _remove_created(self) -> None:
        for d in reversed(self.created):
            try:
                d.rmdir()
            except OSError:
                break
        self.created = []


def _remove(path: Path) -> None:
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink()
    except OSError:
        pass


def _comm(comm):
    if comm is None:
        from mpi4py import MPI
        comm = MPI.COMM_WORLD
    return comm


def _agree(comm, error: str | None) -> None:
    """Rank 0's verdict to every rank: raise OutputError everywhere if it failed."""
    if comm.size > 1:
        error = comm.bcast(error, root=0)
    if error is not None:
        raise OutputError(error)


def reserve(out, comm=None, kind: str = "simulate") -> Path:
    """Check and lock output folder out (collective on comm); returns its real path.

    Raises OutputError on every rank if the folder cannot be used. The lock
    is held until publish() commits or release() is called.
    """
    comm = _comm(comm)
    error: str | None = None
    target: Any = None                    # rank 0's checked path, then every rank's
    if comm.rank == 0:
        try:
            target = check_path(out, kind)
            if target not in _HELD:
                r = Reservation(target, kind)
                with interrupts.critical():       # registered before the lock exists: release() finds it
                    _HELD[target] = r
                    try:
                        r.acquire(str(out))
                    except BaseException:
                        _HELD.pop(target, None)
                        raise
        except OutputError as exc:
            error = str(exc)
    _agree(comm, error)
    if comm.size > 1:
        target = comm.bcast(target, root=0)
    return target


def open_folder(out, comm=None) -> bool:
    """Lock a folder that collects many results (a sweep's) and create it; clean its stale staging.

    Collective. Returns True if this call took the lock (release(out) when done).
    """
    comm = _comm(comm)
    fresh = not held(out) if comm.rank == 0 else False
    target = reserve(out, comm, "sweep")
    error = None
    if comm.rank == 0:
        try:
            made = not target.exists()
            target.mkdir(exist_ok=True)
            # its parents are kept from now on; the folder itself goes with the lock while it is empty (a
            # run interrupted before its first result left an empty folder behind)
            _HELD[target].created = [target] if made else []
            for e in os.listdir(target):
                if re.match(r"^\..+\.(tmp|old)-\d+-[0-9a-f]+$", e) or STALE_FILE.match(e):
                    _remove(target / e)
        except OSError as exc:
            _HELD[target].release()
            error = f"{out}: cannot create it ({exc.strerror})"
    _agree(comm, error)
    return bool(comm.bcast(fresh, root=0)) if comm.size > 1 else fresh


def release(out=None) -> None:
    """Drop the lock on out (every lock this process holds if out is None), nothing published."""
    if out is None:
        for r in list(_HELD.values()):
            r.release()
        return
    target = Path(os.path.realpath(out))
    r = _HELD.get(target)
    if r is not None:
        r.release()


def held(out) -> bool:
    return Path(os.path.realpath(out)) in _HELD


# -- staging and the atomic swap -----------------------------------------------------------------------
def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2); False where the system cannot."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    AT_FDCWD, RENAME_EXCHANGE = -100, 2
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if renameat2(AT_FDCWD, os.fsencode(a), AT_FDCWD, os.fsencode(b), RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


class Stage:
    """The staging folder of one publish(); ``path`` is where the files go (on every rank)."""

    def __init__(self, path: Path, comm):
        self.path, self.comm = path, comm
        self.errors: list[str] = []

    def run(self, fn, *args, **kwargs):
        """Run one writing step on every rank; a failure is recorded (and reported at the end)
        instead of raised, so ranks stay in step through the collective parts of later steps."""
        try:
            return fn(*args, **kwargs)
        except OSError as exc:
            name = getattr(exc, "filename", None)
            self.errors.append(f"cannot write {Path(name).name if name else 'the results'}: "
                               f"{exc.strerror or exc}")
        except Exception as exc:
            from ..runtime import interrupts
            if interrupts.received() is not None:   # an interrupt inside a lazy import (matplotlib...)
                raise interrupts.Interrupted(interrupts.received()) from None
            self.errors.append(f"writing failed: {type(exc).__name__}: {exc}")
        return None


def _carry_over(old: Path, new: Path, kind: str) -> None:
    """Hard-link the other commands' files of the old folder into the new one."""
    if not old.is_dir():
        return
    for e in os.listdir(old):
        if written_by(e) not in (None, kind) and not (new / e).exists():
            try:
                os.link(old / e, new / e)
            except OSError:
                shutil.copy2(old / e, new / e)


def _commit(stage: Path, target: Path, kind: str) -> None:
    _carry_over(target, stage, kind)
    old_content: Path | None = stage          # where the old content ends up (None: there was none)
    with interrupts.critical():
        if target.exists():
            if not _exchange(stage, target):
                old_content = target.parent / f".{target.name}.old-{os.getpid()}-{secrets.token_hex(4)}"
                os.rename(target, old_content)
                os.rename(stage, target)
        else:
            os.rename(stage, target)
            old_content = None
        if ON_COMMIT is not None:
            ON_COMMIT()
    if old_content is not None:
        _remove(old_content)                  # the old content, in the staging name or beside it


@contextmanager
def publish(out, comm=None, kind: str = "simulate"):
    """Stage the files of one result and swap them into out when the block ends cleanly.

    Collective on comm. Inside the block write into ``stage.path`` (wrap each
    writing step in ``stage.run`` under MPI). On a clean exit every rank's
    failures are gathered: with none, rank 0 commits; otherwise (or if the
    block raises) the staging folder is removed and the old content stays.
    The lock is released either way. Raises OutputError on every rank if
    writing or committing failed.
    """
    comm = _comm(comm)
    target = reserve(out, comm, kind)
    res = _HELD.get(target) if comm.rank == 0 else None
    path: Any = None                      # the staging folder (rank 0 makes it, every rank gets it)
    error = None
    committed = False
    try:
        if comm.rank == 0:
            path = target.parent / f".{target.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}"
            try:
                path.mkdir()
            except OSError as exc:
                error = f"{out}: cannot create a staging folder beside it ({exc.strerror})"
        if comm.size > 1:
            path, error = comm.bcast((path, error), root=0)
        if error is not None:
            raise OutputError(error)
        stage = Stage(path, comm)
        yield stage
        errors = stage.errors
        if comm.size > 1:
            errors = sum(comm.gather(errors, root=0) or [], [])
        error = f"{out}: {errors[0]}" if errors else None
        if error is None and comm.rank == 0:
            try:
                _commit(path, target, kind)
                committed = True
            except OSError as exc:
                error = f"{out}: cannot publish the results ({exc.strerror or exc})"
        _agree(comm, error)
        if ON_COMMIT is not None:                 # the other ranks (rank 0 did it at the rename)
            ON_COMMIT()
    finally:
        if comm.rank == 0:
            if not committed and path is not None:
                _remove(path)
            if res is not None:
                res.release(keep_parents=committed)
