"""Files: rank-0 printing, atomic writes, strict JSON (null for non-finite), text, CSV and design TOML.
"""
from __future__ import annotations

import errno
import json
import os
import tempfile
from pathlib import Path

import numpy as np


FORMAT = 1


# -- small helpers ---------------------------------------------------------------------------
# A write that fails for want of room or permission on the file system is the user's to fix (exit 1,
# one line), in every command; anything else failing while writing is still an internal error.
DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG, errno.EACCES, errno.EPERM})


def disk_error(exc: BaseException) -> str | None:
    """The one-line message of a full, read-only or over-quota file system error, or None."""
    if isinstance(exc, OSError) and exc.errno in DISK_ERRNOS:
        name = Path(exc.filename).name if getattr(exc, "filename", None) else "the results"
        return f"cannot write {name}: {exc.strerror or os.strerror(exc.errno)}"
    return None


def say(*args, **kwargs) -> None:
    """print, on MPI rank 0 only (progress lines of studies and scripts)."""
    from mpi4py import MPI
    if MPI.COMM_WORLD.rank == 0:
        print(*args, **kwargs)


def atomic_write(path: Path, write) -> None:
    """Call write(tmp_path) and rename the result onto path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def copy_figure(picture: Path, folder: Path | None) -> None:
    """Copy a study's picture into folder (the docs' figures), atomically; nothing if folder is None."""
    if folder is not None:
        data = Path(picture).read_bytes()
        atomic_write(Path(folder) / Path(picture).name, lambda tmp: Path(tmp).write_bytes(data))


def strict_json(value):
    """value with numpy types made plain and every non-finite float (NaN, +-Infinity) made None.

    JSON has no NaN or Infinity; Python's json module would write them anyway
    (and most readers then fail), so skelfem writes null instead.
    """
    if isinstance(value, dict):
        return {str(k): strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return [strict_json(v) for v in value.tolist()]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if np.isfinite(v) else None
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: Path, data: dict) -> None:
    """data as strict JSON (non-finite numbers as null), atomically."""
    text = json.dumps(strict_json(data), indent=2, allow_nan=False) + "\n"

    def write(tmp):
        with open(tmp, "w") as f:
            f.write(text)
    atomic_write(path, write)


def write_text(path: Path, text: str) -> None:
    """A text file, atomically."""
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))


def write_csv(path: Path, fields, rows) -> None:
    """Rows (dicts) as CSV with the given columns (missing values empty), atomically."""
    import csv

    def write(tmp):
        with open(tmp, "w", newline="") as f:
            w = csv.DictWriter(f, list(fields), extrasaction="ignore")
            w.writeheader()
            for r in rows:
                w.writerow({k: r.get(k, "") for k in fields})
    atomic_write(path, write)




class CsvStream:
    """A CSV file written a row at a time (a long run's rows never all in memory); close() ends it."""

    def __init__(self, path: Path, fields):
        import csv
        self.fields = list(fields)
        self.file = open(path, "w", newline="")
        try:
            self.writer = csv.DictWriter(self.file, self.fields, extrasaction="ignore")
            self.writer.writeheader()
        except BaseException:
            self.file.close()
            raise

    def write(self, row: dict) -> None:
        self.writer.writerow({k: row.get(k, "") for k in self.fields})

    def close(self) -> None:
        if not self.file.closed:
            self.file.flush()
            self.file.close()


class InputTooLarge(ValueError):
    """A file given as input is larger than its kind may be."""


def read_bounded(path, limit: int, what: str) -> str:
    """The UTF-8 text of an input file, reading at most limit + 1 bytes: an endless or huge input
    (/dev/zero, a pipe that never ends) is refused after limit bytes instead of filling memory.
    OSError and UnicodeDecodeError pass through; InputTooLarge when the file is over the limit."""
    with open(path, "rb") as fh:
        raw = fh.read(limit + 1)
    if len(raw) > limit:
        raise InputTooLarge(f"{path}: larger than {limit // 2 ** 20} MB; not a {what}")
    return raw.decode("utf-8")


def design_toml(d: dict) -> str:
    """TOML text of a design dict: sections as tables, lists of tables as [[...]], the rest inline (studies
    and tests write designs with it; the editor's Save edits a file in place instead)."""
    import tomlkit

    def inline(v):                        # below a section's own keys: inline tables and arrays
        if isinstance(v, dict):
            t = tomlkit.inline_table()
            t.update({k: inline(x) for k, x in v.items()})
            return t
        if isinstance(v, (list, tuple)):
            a = tomlkit.array()
            a.extend(inline(x) for x in v)
            return a
        return v

    def section(v: dict):
        t = tomlkit.table()
        for k, x in v.items():
            t.add(k, inline(x))
        return t

    doc = tomlkit.document()
    for k, v in d.items():
        if isinstance(v, dict):
            doc.add(k, section(v))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            aot = tomlkit.aot()
            for x in v:
                aot.append(section(x))
            doc.add(k, aot)
        else:
            doc.add(k, inline(v))
    return tomlkit.dumps(doc)
