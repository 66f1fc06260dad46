"""Safe output: atomic file writes, staged report folders, output checks.

Every file lftomo writes goes first to a temporary file in the same folder
(a hidden name ``.<name>.tmp-<pid>-<random><suffix>``), is flushed to disk
(``fsync``) and then renamed over the final name with :func:`os.replace`,
which is atomic on POSIX and Windows.  A reader therefore sees either the
previous file or the complete new one, never a partial file, even when the
writer is interrupted (Ctrl-C) or killed.

Folders of several files (``lftomo render``, ``demo``, ``reconstruct``) are
written into a staging folder inside the output folder and published at the
end: the old report files (``index.html``, ``metrics.json``,
``summary.json``) and the completion marker :data:`COMPLETE_MARKER` are
removed first, the new files are moved in, the report files last and the
marker after them.  An interrupted run leaves the previous output untouched
or, if it was interrupted while publishing, no report that could contradict
the files beside it.

Output locations are checked before the work starts (:func:`check_output_dir`,
:func:`check_output_file`).
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import signal
import threading
import time
from pathlib import Path
from typing import Any, Iterator, Sequence

from .errors import LftomoError

__all__ = ["atomic_path", "atomic_write_text", "check_output_dir", "check_output_file", "npz_output_path",
           "staged_directory", "deferred_sigint", "ResumableRows", "COMPLETE_MARKER", "REPORT_FILES"]

#: Name of the file that marks an output folder as complete (written last).
COMPLETE_MARKER = "lftomo-complete.json"
#: Files that describe the others; removed first and published last.
REPORT_FILES = ("index.html", "metrics.json", "summary.json")
_STAGE_PREFIX = ".lftomo-partial-"


def _fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable (no-op where directories cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # pragma: no cover - e.g. Windows
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


def _fsync_file(path: Path) -> None:
    with open(path, "rb+") as fh:
        os.fsync(fh.fileno())


@contextlib.contextmanager
def deferred_sigint() -> Iterator[None]:
    """Hold Ctrl-C (SIGINT) during a short critical section, then raise it.

    Only in the main thread (elsewhere signals cannot be handled and this is a no-op).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[Any] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` atomically.

    The temporary name keeps the suffix of ``path`` (so writers that choose a
    format from it, e.g. numpy, PIL, matplotlib, behave the same).  On any
    exception, including KeyboardInterrupt, the temporary file is removed and
    ``path`` is left as it was.

    Examples
    --------
    >>> with atomic_path("weights.npz") as tmp:   # doctest: +SKIP
    ...     np.savez(tmp, a=a)
    """
    final = Path(path)
    tmp = final.with_name(f".{final.stem}.tmp-{os.getpid()}-{secrets.token_hex(4)}{final.suffix}")
    try:
        yield tmp
        if not tmp.is_file():
            raise LftomoError(f"nothing was written for {str(final)!r}")
        _fsync_file(tmp)
        with deferred_sigint():
            os.replace(tmp, final)
            _fsync_dir(final.parent)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def check_output_dir(path: Any, *, what: str = "output folder", create: bool = True,
                     command: str | None = None) -> Path:
    """Check, before any work, that ``path`` is (or can be made) a writable folder.

    With ``command`` (the ``lftomo`` sub-command that will publish there with
    :func:`staged_directory`), a folder that holds the complete output of
    another command (its :data:`COMPLETE_MARKER` names that command) is
    refused: publishing replaces the report files, so the folder would mix two
    runs' files under one run's report.

    Raises
    ------
    LftomoError
        If ``path`` is a file, lies under a file, is not writable, or holds
        another command's output.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise LftomoError(f"{what} must be a path (str or os.PathLike), got {type(path).__name__}")
    p = Path(path)
    for q in [p, *p.parents]:
        if q.exists() and not q.is_dir():
            raise LftomoError(f"{what} {str(p)!r}: {str(q)!r} is a file, not a folder")
        if q.exists():
            break
    if create:
        try:
            p.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise LftomoError(f"{what} {str(p)!r} cannot be created: {exc.strerror or exc}") from None
    target = p if p.exists() else next(q for q in p.parents if q.exists())
    if not os.access(target, os.W_OK | os.X_OK):
        raise LftomoError(f"{what} {str(p)!r} is not writable ({str(target)!r})")
    other = _published_by(p)
    if command is not None and other is not None and other != command:
        raise LftomoError(f"{what} {str(p)!r} holds the output of `lftomo {other}` ({COMPLETE_MARKER}); write "
                          f"`lftomo {command}` to another folder (its report would replace that run's and the "
                          "folder would mix the two runs' files)")
    return p


def _published_by(folder: Path) -> str | None:
    """The command whose output ``folder`` holds: the one its completion marker names, or ``"series"`` for a
    time series' folder (which grows frame by frame and keeps a manifest instead); None if neither."""
    marker = _marker(folder)
    if marker is None:
        return "series" if _is_series_folder(folder) else None
    command = marker.get("command")
    return command if isinstance(command, str) else None


def _marker(folder: Path) -> dict | None:
    """``folder``'s completion marker as a dict (None: none, or unreadable)."""
    try:
        marker = json.loads((folder / COMPLETE_MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return marker if isinstance(marker, dict) else None


#: The manifest a time series keeps in its output folder, and the format it names.
SERIES_MANIFEST, SERIES_FORMAT_PREFIX = "manifest.json", "lftomo-series"


def _is_series_folder(folder: Path) -> bool:
    try:
        doc = json.loads((folder / SERIES_MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and str(doc.get("format", "")).startswith(SERIES_FORMAT_PREFIX)


def _previous_files(out: Path, command: str | None) -> list[str]:
    """The files the previous run of ``command`` published in ``out`` (plain names only), from its marker."""
    marker = _marker(out)
    if marker is None or marker.get("command") != command or not isinstance(marker.get("files"), list):
        return []
    return [f for f in marker["files"]
            if isinstance(f, str) and f not in ("", ".", "..") and "\x00" not in f and Path(f).name == f]


def check_output_file(path: Any, *, what: str = "output file") -> Path:
    """Check, before any work, that ``path`` can be written: its folder exists and
    is writable, and ``path`` is not a folder or another non-regular file."""
    if not isinstance(path, (str, os.PathLike)):
        raise LftomoError(f"{what} must be a path (str or os.PathLike), got {type(path).__name__}")
    p = Path(path)
    if not p.parent.is_dir():
        raise LftomoError(f"{what}: directory {str(p.parent)!r} does not exist")
    if p.exists() and not p.is_file():
        raise LftomoError(f"{what} {str(p)!r} exists and is not a regular file (a folder?)")
    if not os.access(p.parent, os.W_OK | os.X_OK):
        raise LftomoError(f"{what} {str(p)!r}: directory {str(p.parent)!r} is not writable")
    return p


def npz_output_path(path: Any, *, what: str = "output file") -> Path:
    """``path`` with the suffix ``.npz`` (replacing another suffix: ``W.mat`` is written as ``W.npz``), checked
    by :func:`check_output_file`; an existing folder given as ``path`` is
    refused rather than written beside as ``folder.npz``."""
    if isinstance(path, (str, os.PathLike)) and Path(path).is_dir():
        raise LftomoError(f"{what} {str(path)!r} is a folder; give a file name such as "
                          f"{str(Path(path) / 'out.npz')!r}")
    p = Path(path) if isinstance(path, (str, os.PathLike)) else path
    if isinstance(p, Path) and p.suffix != ".npz":
        p = p.with_suffix(".npz")
    return check_output_file(p, what=what)


class ResumableRows:
    """Result rows of a long study, kept one per line (JSON Lines) so that a rerun resumes.

    Each finished row is appended to ``path`` as one JSON line and flushed to
    disk (``fsync``) before the next one starts.  A rerun with the same
    ``settings`` finds the rows already done (:meth:`get`) and computes only
    the rest; a file written with other settings is set aside as
    ``<path>.old`` (not mixed in).  A line cut by an interruption or a crash is
    ignored (that row is computed again).

    Parameters
    ----------
    path : path
        The rows file (created; its folder must exist).
    settings : dict
        JSON-serialisable description of everything the rows depend on (the
        study's arguments): its first line.

    Examples
    --------
    >>> rows = ResumableRows("draws.jsonl", vars(args))      # doctest: +SKIP
    >>> for d in range(n):                                     # doctest: +SKIP
    ...     row = rows.get(d) or rows.add(d, compute(d))
    """

    def __init__(self, path: str | os.PathLike, settings: dict[str, Any]) -> None:
        self.path = check_output_file(path, what="rows file")
        self.settings = json.loads(json.dumps(settings, sort_keys=True, default=str))
        self.rows: dict[str, Any] = {}
        if self.path.is_file():
            lines = self.path.read_text(encoding="utf-8").splitlines()
            head = self._parse(lines[0]) if lines else None
            if isinstance(head, dict) and head.get("settings") == self.settings:
                for line in lines[1:]:
                    item = self._parse(line)
                    if isinstance(item, dict) and "key" in item and "row" in item:
                        self.rows[str(item["key"])] = item["row"]
                self._rewrite()  # drop a cut last line before appending
                return
            os.replace(self.path, self.path.with_name(self.path.name + ".old"))
        self._rewrite()

    @staticmethod
    def _parse(line: str) -> Any:
        try:
            return json.loads(line)
        except json.JSONDecodeError:
            return None

    def _rewrite(self) -> None:
        lines = [json.dumps({"settings": self.settings}, sort_keys=True)]
        lines += [json.dumps({"key": k, "row": r}, default=float) for k, r in self.rows.items()]
        atomic_write_text(self.path, "\n".join(lines) + "\n")

    def get(self, key: Any) -> Any:
        """The row stored under ``key`` (compared as a string), or None."""
        return self.rows.get(str(key))

    def add(self, key: Any, row: Any) -> Any:
        """Append ``row`` (JSON-serialisable) under ``key``, durably; returns ``row``."""
        line = json.dumps({"key": str(key), "row": row}, default=float)  # numpy scalars as numbers
        with deferred_sigint(), open(self.path, "a", encoding="utf-8") as fh:
            fh.write(line + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        self.rows[str(key)] = json.loads(line)["row"]
        return row


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # pragma: no cover - someone else's process
        return True
    return True


def _remove_stale_stages(out: Path) -> None:
    """Remove staging folders of runs that were killed (their process is gone)."""
    for d in out.glob(_STAGE_PREFIX + "*"):
        try:
            pid = int(d.name[len(_STAGE_PREFIX):].split("-")[0])
        except ValueError:
            continue
        if d.is_dir() and not _pid_alive(pid):
            shutil.rmtree(d, ignore_errors=True)


def _publish(stage: Path, out: Path, last: Sequence[str], command: str | None) -> list[str]:
    names = sorted(f.name for f in stage.iterdir() if f.is_file())
    first = [n for n in names if n not in last]
    final = [n for n in names if n in last]
    stale = [n for n in _previous_files(out, command) if n not in names]  # a rerun's folder holds this run only
    with deferred_sigint():
        for n in (COMPLETE_MARKER, *last):
            with contextlib.suppress(FileNotFoundError):
                (out / n).unlink()
        for n in stale:  # best effort: a stale file that cannot be removed does not stop the publishing
            with contextlib.suppress(OSError, ValueError):
                (out / n).unlink()
        _fsync_dir(out)
        for n in first + final:
            os.replace(stage / n, out / n)
        _fsync_dir(out)
        marker = {"complete": True, "files": names, "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                  **({"command": command} if command else {})}
        atomic_write_text(out / COMPLETE_MARKER, json.dumps(marker, indent=2))
    shutil.rmtree(stage, ignore_errors=True)
    return names


@contextlib.contextmanager
def staged_directory(out: str | os.PathLike, *, last: Sequence[str] = REPORT_FILES,
                     command: str | None = None) -> Iterator[Path]:
    """Write a folder of outputs in a staging folder, publish it on success.

    Publishing also removes the files that the previous run of the same ``command`` listed in
    the folder's marker and this run does not write (plain names only); no other file is touched.

    Parameters
    ----------
    out : path
        The output folder (created; checked first with :func:`check_output_dir`).
    last : sequence of str
        File names that describe the others (reports); they are removed from
        ``out`` before publishing and moved in last.
    command : str, optional
        The ``lftomo`` sub-command publishing: named in the marker, and a folder
        holding another command's output is refused (:func:`check_output_dir`).

    Yields
    ------
    Path
        The staging folder (``out/.lftomo-partial-<pid>-<random>``): write every file there.

    Notes
    -----
    On an exception (or Ctrl-C) the staging folder is removed and ``out`` is
    left as it was.  On success the files are moved into ``out`` one by one
    (each move is atomic) and :data:`COMPLETE_MARKER` is written last,
    listing them.
    """
    out = check_output_dir(out, command=command)
    _remove_stale_stages(out)
    stage = out / f"{_STAGE_PREFIX}{os.getpid()}-{secrets.token_hex(3)}"
    stage.mkdir()
    try:
        yield stage
        _publish(stage, out, tuple(last), command)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


# ---------------------------------------------------------------- reading .npz safely
def _member_header(zf, name: str):
    """(shape, dtype, header bytes end offset) of an .npy member, read without loading it."""
    import numpy as np
    from numpy.lib import format as npf

    with zf.open(name) as fh:
        version = npf.read_magic(fh)
        if version == (1, 0):
            shape, fortran, dtype = npf.read_array_header_1_0(fh)
        elif version in ((2, 0), (3, 0)):
            shape, fortran, dtype = npf.read_array_header_2_0(fh)
        else:  # pragma: no cover - numpy raises first
            raise LftomoError(f"unknown .npy version {version}")
        offset = fh.tell()
    return shape, np.dtype(dtype), offset


def read_npz(path: str | os.PathLike, *, what: str, needs: str, limit: Any = None) -> dict[str, Any]:
    """Read every array of an ``.npz`` archive without pickle, as one checked step.

    Each member's header is read first: object dtypes are refused, and the
    size it announces must match the bytes the member holds (a truncated or
    tampered member is reported, not read) and fit the memory limit.

    Parameters
    ----------
    path : path-like
    what : str
        Kind of file for messages, e.g. ``"light-field file"``.
    needs : str
        What a good file is, appended to "not an .npz archive" messages.
    limit : float, optional
        Memory limit in bytes (default :func:`lftomo._validate.memory_limit`).

    Returns
    -------
    dict of str to ndarray

    Raises
    ------
    LftomoError
        Naming the file and the member.
    """
    return _npz(path, what=what, needs=needs, limit=limit, load=True)


def npz_shapes(path: str | os.PathLike, *, what: str, needs: str, limit: Any = None) -> dict[str, tuple]:
    """The shape of every array of an ``.npz`` archive, from the members' headers, with
    :func:`read_npz`'s checks (no objects, sizes that match the bytes, the memory limit) but
    without reading the arrays.

    Returns
    -------
    dict of str to tuple of int
    """
    return _npz(path, what=what, needs=needs, limit=limit, load=False)


def _npz(path: Any, *, what: str, needs: str, limit: Any, load: bool) -> dict[str, Any]:
    """Every member's header checked; then the arrays (``load``) or their shapes."""
    import zipfile

    import numpy as np

    from ._validate import check_allocation, require_npz_file

    p = require_npz_file(path, what=what, needs=needs)
    out: dict[str, Any] = {}
    member = None
    try:
        with zipfile.ZipFile(p) as zf:
            infos = [i for i in zf.infolist() if not i.is_dir()]
            for info in infos:
                member = info.filename
                if not member.endswith(".npy"):
                    raise LftomoError(f"{what} {str(p)!r}: member {member!r} is not an .npy array")
                shape, dtype, offset = _member_header(zf, member)
                name = member[:-4]
                if dtype.hasobject:
                    raise LftomoError(f"{what} {str(p)!r}: member {name!r} holds Python objects (dtype {dtype}) "
                                      "that cannot be read without pickling; lftomo never unpickles")
                nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if offset + nbytes != info.file_size:
                    raise LftomoError(f"{what} {str(p)!r}: member {name!r} announces shape {tuple(shape)} "
                                      f"({nbytes} bytes) but holds {info.file_size - offset} bytes: truncated "
                                      "or corrupt")
                check_allocation(f"{what} {str(p)!r} member {name!r}", nbytes, limit=limit)
                out[name] = tuple(shape)
            if load:
                for info in infos:
                    member = info.filename
                    with zf.open(member) as fh:
                        out[member[:-4]] = np.lib.format.read_array(fh, allow_pickle=False)
    except LftomoError:
        raise
    except Exception as exc:  # noqa: BLE001 - any failure to decode damaged bytes (BadZipFile, zlib.error,
        # EOFError, tokenize.TokenError from a mangled .npy header, ...) is the file's fault, not a bug
        where = f" member {member[:-4]!r}" if member else ""
        raise LftomoError(f"{what} {str(p)!r}{where} cannot be read ({type(exc).__name__}: {exc}); "
                          "the file is corrupt or truncated") from None
    return out


def json_member(arrays: dict[str, Any], *, path: Any, what: str, name: str = "meta") -> dict[str, Any]:
    """Decode the JSON text stored as the 0-d string member ``name``; must be a JSON object."""
    a = arrays.get(name)
    if a is None or getattr(a, "dtype", None) is None or a.dtype.kind != "U" or a.ndim != 0:
        raise LftomoError(f"{what} {str(path)!r}: member {name!r} (JSON metadata, a 0-d string) is missing or "
                          f"malformed" + ("" if a is None else f" (dtype {a.dtype}, shape {a.shape})"))
    try:
        d = json.loads(str(a))
    except (ValueError, RecursionError) as exc:
        raise LftomoError(f"{what} {str(path)!r}: member {name!r} is not valid JSON: {exc}") from None
    if not isinstance(d, dict):
        raise LftomoError(f"{what} {str(path)!r}: member {name!r} must be a JSON object, got {type(d).__name__}")
    return d


def check_member(arrays: dict[str, Any], name: str, *, path: Any, what: str, kinds: str = "f",
                 shape: tuple[int, ...] | None = None, ndim: int | None = None, minimum: float | None = None,
                 maximum: float | None = None, required: bool = True):
    """Check member ``name``: present, dtype kind in ``kinds`` ('f' float, 'i' signed,
    'u' unsigned int), shape or ndim, finite, within ``[minimum, maximum]``.

    Returns the array (None if absent and not ``required``).
    """
    import numpy as np

    a = arrays.get(name)
    where = f"{what} {str(path)!r}: member {name!r}"
    if a is None:
        if required:
            raise LftomoError(f"{where} is missing; it holds {sorted(arrays)}")
        return None
    if a.dtype.kind not in kinds:
        raise LftomoError(f"{where} has dtype {a.dtype}; expected {'a float' if kinds == 'f' else 'an integer'} "
                          "dtype")
    if shape is not None and tuple(a.shape) != tuple(shape):
        raise LftomoError(f"{where} has shape {tuple(a.shape)}, expected {tuple(shape)}")
    if ndim is not None and a.ndim != ndim:
        raise LftomoError(f"{where} must be {ndim}-D, got shape {tuple(a.shape)}")
    if a.dtype.kind == "f" and a.size and not np.all(np.isfinite(a)):
        raise LftomoError(f"{where} has {int(np.count_nonzero(~np.isfinite(a)))} non-finite value(s) (NaN or inf)")
    if minimum is not None and a.size and a.min() < minimum:
        raise LftomoError(f"{where} must be >= {minimum:g}, got minimum {a.min().item()!r}")
    if maximum is not None and a.size and a.max() > maximum:
        raise LftomoError(f"{where} must be <= {maximum:g}, got maximum {a.max().item()!r}")
    return a


def read_npy(path: str | os.PathLike, *, what: str, limit: Any = None):
    """Read one ``.npy`` array without pickle, its header checked first (as :func:`read_npz`).

    Raises
    ------
    LftomoError
        Not an ``.npy`` file, object dtype, a size that does not match the
        file (truncated), above the memory limit, or undecodable.
    """
    import numpy as np
    from numpy.lib import format as npf

    from ._validate import check_allocation, require_regular_file

    p = require_regular_file(path, what=what)
    try:
        with open(p, "rb") as fh:
            if fh.read(6) != b"\x93NUMPY":
                raise LftomoError(f"{what} {str(p)!r} is not an .npy file (numpy.save)")
            fh.seek(0)
            version = npf.read_magic(fh)
            header = npf.read_array_header_1_0 if version == (1, 0) else npf.read_array_header_2_0
            shape, _, dtype = header(fh)
            dtype = np.dtype(dtype)
            if dtype.hasobject:
                raise LftomoError(f"{what} {str(p)!r} holds Python objects (dtype {dtype}) that cannot be read "
                                  "without pickling; lftomo never unpickles")
            nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
            if fh.tell() + nbytes != p.stat().st_size:
                raise LftomoError(f"{what} {str(p)!r} announces shape {tuple(shape)} ({nbytes} bytes) but holds "
                                  f"{p.stat().st_size - fh.tell()} bytes: truncated or corrupt")
            check_allocation(f"{what} {str(p)!r}", nbytes, limit=limit)
            fh.seek(0)
            return np.load(fh, allow_pickle=False)
    except LftomoError:
        raise
    except Exception as exc:  # noqa: BLE001 - damaged bytes
        raise LftomoError(f"{what} {str(p)!r} cannot be read ({type(exc).__name__}: {exc}); the file is corrupt "
                          "or truncated") from None
