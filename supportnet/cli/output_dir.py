"""Output folders nobody can break: claimed before any work, built under a temporary name, renamed
when complete, marked as supportnet's.

The rules every command follows (DESIGN.md, CLI contract):

- ``--out`` never removes anything supportnet did not write. ``--overwrite`` replaces only a folder
  holding the marker :data:`MARKER` (JSON: who wrote it, the command, the version, when), and never
  the current folder, a folder holding it, an input (the data, maps, a model) or a folder holding
  an input or inside one.
- Every refusal about the output path is found by :func:`claim_output` *before any work*, as one
  :class:`~calib.errors.DataError` naming the path first and what to do; :func:`atomic_output`
  checks again before it renames.
- Work goes to ``.<name>.supportnet-tmp-<pid>-<hex>`` beside the output, removed on any failure,
  Ctrl-C or SIGTERM; what a killed run (``kill -9``) left is removed by the next run that claims the
  same output, once its process is gone.
- Folders and files follow the user's umask (no private ``mkdtemp`` folders).
- JSON is strict: :func:`write_json` writes ``null`` for NaN and infinities, never ``NaN``.
"""

from __future__ import annotations

import json
import math
import os
import re
import secrets
import shutil
import signal
import socket
import threading
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import yaml
from pydantic import BaseModel
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    Task,
    TaskID,
    TextColumn,
    TimeRemainingColumn,
)
from rich.text import Text

from calib.errors import DataError

__all__ = [
    "MARKER",
    "atomic_output",
    "claim_output",
    "claim_partial",
    "is_supportnet_output",
    "make_parents",
    "make_temp_dir",
    "progress_bar",
    "read_marker",
    "remove_empty",
    "removed_on_failure",
    "replace_atomically",
    "resolved_config",
    "sweep_leftovers",
    "temp_path",
    "write_json",
    "write_marker",
]

MARKER = ".supportnet-output"
"""The file supportnet writes inside every folder it creates; ``--overwrite`` needs it."""

_TAG = ".supportnet-"
_LEFTOVER = re.compile(r"\.supportnet-(?:tmp|old)-(\d+)-[0-9a-f]+")
_NAME_KEEP = 150  # characters of the output's name kept in a temporary name (NAME_MAX is 255)


# -- the marker ---------------------------------------------------------------------------------


def _command() -> str:
    """The running ``supportnet`` command (``maps``, ``calibrate``, ...), or ``library``."""
    try:
        import click

        ctx = click.get_current_context(silent=True)
    except ImportError:  # pragma: no cover - click comes with typer
        ctx = None
    return ctx.info_name if ctx is not None and ctx.info_name else "library"


def write_marker(folder: Path, command: str | None = None, **extra: object) -> None:
    """Mark ``folder`` as written by supportnet: :data:`MARKER` holds the command, the version,
    the time, the process and host (for the clean-up of killed runs) and ``extra``."""
    from supportnet import __version__

    marker = {
        "written_by": "supportnet",
        "command": command or _command(),
        "version": __version__,
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "pid": os.getpid(),
        "host": socket.gethostname(),
        **extra,
    }
    write_json(Path(folder) / MARKER, marker)


def read_marker(folder: Path) -> dict | None:
    """What :data:`MARKER` in ``folder`` holds, or ``None`` where supportnet did not write it."""
    path = Path(folder) / MARKER
    try:
        marker = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return marker if isinstance(marker, dict) and marker.get("written_by") == "supportnet" else None


def is_supportnet_output(folder: Path) -> bool:
    """Whether ``folder`` is a real folder (not a link) that supportnet wrote."""
    folder = Path(folder)
    return folder.is_dir() and not folder.is_symlink() and read_marker(folder) is not None


# -- claiming an output -------------------------------------------------------------------------


def _absolute(path: Path) -> Path:
    return Path(os.path.abspath(path)).resolve()


def _inside(path: Path, folder: Path) -> bool:
    """``path`` is ``folder`` or lies under it (both absolute and resolved)."""
    return path == folder or folder in path.parents


def _nearest_existing(path: Path) -> Path:
    for candidate in (path, *path.parents):
        if os.path.lexists(candidate):
            return candidate
    return Path(path.anchor or ".")


def claim_output(
    out: Path, overwrite: bool = False, inputs: Iterable[Path | None] = (), *, file: bool = False
) -> None:
    """Check everything about ``out`` before any work, so a refusal costs nothing.

    Also removes what killed runs left beside ``out`` (see :func:`sweep_leftovers`).

    Args:
        out: the folder a command writes (``file=True``: the file, e.g. an ONNX model).
        overwrite: ``--overwrite``: an existing ``out`` may be replaced, if supportnet wrote it.
        inputs: what the command reads (data, maps, a model); ``None`` entries are skipped.
        file: ``out`` is one file, not a folder (no marker inside to check).

    Raises:
        DataError: one line, starting with ``out``, saying what is wrong and what to do.
    """
    out = Path(out)
    here, cwd = _absolute(out), Path.cwd().resolve()
    if _inside(cwd, here):
        raise DataError(
            out,
            "is the current folder or a folder holding it; supportnet never writes over it; "
            "choose a new folder for --out",
        )
    exists = os.path.lexists(out)
    for source in (Path(p) for p in inputs if p is not None):
        there = _absolute(source)
        if here == there:
            raise DataError(out, f"is also an input ({source}); choose another --out")
        if _inside(there, here):
            raise DataError(out, f"holds an input ({source}); choose another --out")
        if exists and overwrite and _inside(here, there):
            raise DataError(
                out,
                f"lies inside an input ({source}); --overwrite never replaces a folder there; "
                "choose another --out",
            )
    sweep_leftovers(out.parent, out.name)
    base = _nearest_existing(out.parent)
    if not base.is_dir():
        raise DataError(out, f"cannot be created: {base} is a file, not a folder; choose another --out")
    if not os.access(base, os.W_OK | os.X_OK):
        raise DataError(out, f"cannot be written: no permission to write in {base}; choose another --out")
    if not exists:
        return
    if not overwrite:
        raise DataError(out, "already exists; pass --overwrite to replace it")
    if out.is_symlink():
        raise DataError(
            out,
            "is a symbolic link; --overwrite replaces only a folder supportnet wrote; remove the "
            "link or choose another --out",
        )
    if file:
        if out.is_dir():
            raise DataError(out, "is a folder; --out takes the file to write")
        return
    if not out.is_dir():
        raise DataError(
            out, "is a file, not a folder supportnet wrote; remove it yourself or choose another --out"
        )
    if read_marker(out) is None:
        raise DataError(
            out,
            f"was not written by supportnet (no {MARKER} inside), so --overwrite leaves it alone; "
            "remove it yourself or choose another --out",
        )
    if not os.access(out, os.W_OK | os.X_OK):
        raise DataError(out, "cannot be replaced: no permission to write in it; choose another --out")


# -- temporary folders and leftovers --------------------------------------------------------------


def _alive(pid: int, folder: Path) -> bool:
    """Whether the run that made ``folder`` may still be going (when in doubt: yes)."""
    marker = read_marker(folder)
    if marker is not None and marker.get("host") not in (None, socket.gethostname()):
        return True  # another machine's process (a shared disk): its pid means nothing here
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OverflowError, ValueError):
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def sweep_leftovers(parent: Path, name: str) -> list[Path]:
    """Remove ``.<name>.supportnet-tmp-<pid>-<hex>`` (and ``-old-``) folders and files in ``parent``
    whose process is gone (killed with ``kill -9``, a power cut). Nothing else is ever touched.

    Returns:
        The folders removed.
    """
    parent = Path(parent)
    prefix = f".{name[:_NAME_KEEP]}"
    removed = []
    try:
        entries = [e for e in parent.iterdir() if e.name.startswith(prefix + _TAG)]
    except OSError:
        return removed
    for entry in entries:
        match = _LEFTOVER.fullmatch(entry.name[len(prefix) :])
        if not match or entry.is_symlink() or _alive(int(match[1]), entry):
            continue
        if entry.is_dir():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
        removed.append(entry)
    return removed


def _temp_name(parent: Path, name: str, kind: str = "tmp") -> Path:
    return Path(parent) / f".{name[:_NAME_KEEP]}{_TAG}{kind}-{os.getpid()}-{secrets.token_hex(4)}"


def temp_path(out: Path) -> Path:
    """A fresh name beside the file ``out`` to write it under before a rename (nothing is created;
    a file made there follows the umask, and :func:`sweep_leftovers` removes it after a kill)."""
    out = Path(out)
    return _temp_name(out.parent, out.name)


def make_parents(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents (umask's mode); returns those created, deepest
    first, for :func:`remove_empty` to take back after a failure."""
    folder = Path(folder)
    missing = [p for p in (folder, *folder.parents) if not os.path.lexists(p)]
    folder.mkdir(parents=True, exist_ok=True)
    return missing


def remove_empty(folders: Iterable[Path]) -> None:
    """Remove each of ``folders`` (deepest first) that is still empty; anything else stays."""
    for folder in folders:
        try:
            Path(folder).rmdir()
        except OSError:
            return


def make_temp_dir(parent: Path, name: str, command: str | None = None) -> Path:
    """A new marked folder ``parent/.<name>.supportnet-tmp-<pid>-<hex>`` with the umask's mode
    (``tempfile.mkdtemp`` would make it private). ``parent`` must exist."""
    parent = Path(parent)
    while True:
        tmp = _temp_name(parent, name)
        try:
            tmp.mkdir()  # 0o777 less the umask
        except FileExistsError:
            continue
        break
    try:
        write_marker(tmp, command)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return tmp


@contextmanager
def _signals_held() -> Iterator[None]:
    """Ctrl-C and SIGTERM wait until the block is done (a rename pair is never cut in half)."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def replace_atomically(moves: Iterable[tuple[Path, Path]]) -> None:
    """Rename each ``(new, dest)``; a ``dest`` already there is moved aside first and removed after.
    Signals wait until every rename is done, and a failed rename puts back what it moved.

    The caller has checked with :func:`claim_output` that each ``dest`` may be replaced.
    """
    aside: list[tuple[Path, Path]] = []
    done: list[tuple[Path, Path]] = []
    with _signals_held():
        try:
            for new, dest in moves:
                new, dest = Path(new), Path(dest)
                if os.path.lexists(dest):
                    old = _temp_name(dest.parent, dest.name, "old")
                    dest.rename(old)
                    aside.append((old, dest))
                dest.parent.mkdir(parents=True, exist_ok=True)
                new.rename(dest)
                done.append((new, dest))
        except BaseException:
            for new, dest in reversed(done):
                dest.rename(new)
            for old, dest in reversed(aside):
                old.rename(dest)
            raise
    for old, _ in aside:
        shutil.rmtree(old, ignore_errors=True) if old.is_dir() and not old.is_symlink() else old.unlink()


@contextmanager
def atomic_output(
    out: Path,
    overwrite: bool = False,
    inputs: Iterable[Path | None] = (),
    *,
    command: str | None = None,
) -> Iterator[Path]:
    """Yield a marked temporary folder beside ``out``; on success it replaces ``out`` in one rename.

    ``out`` is claimed (:func:`claim_output`) on entry and again before the rename (another run
    may have written it meanwhile). On any error, Ctrl-C or SIGTERM the temporary folder is
    removed, so nothing half-written is left behind.
    """
    out = Path(out)
    inputs = list(inputs)
    claim_output(out, overwrite, inputs)
    created = make_parents(out.parent)
    try:
        tmp = make_temp_dir(out.parent, out.name, command)
    except BaseException:
        remove_empty(created)
        raise
    try:
        yield tmp
        claim_output(out, overwrite, inputs)
        replace_atomically([(tmp, out)])
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        remove_empty(created)
        raise


@contextmanager
def removed_on_failure(folder: Path) -> Iterator[None]:
    """On any error, Ctrl-C or SIGTERM, remove ``folder`` if this process marked it (a work folder
    with a fixed name, e.g. training's ``<out>.partial``); otherwise leave it."""
    try:
        yield
    except BaseException:
        marker = read_marker(folder) if Path(folder).is_dir() and not Path(folder).is_symlink() else None
        if marker is not None and marker.get("pid") == os.getpid():
            shutil.rmtree(folder, ignore_errors=True)
        raise


def claim_partial(partial: Path, resume: bool, **expected: object) -> bool:
    """Decide what to do with ``partial``, the resumable work folder of an interrupted run.

    - absent: nothing (returns ``False``);
    - not supportnet's: refused, never removed;
    - another live process's: refused;
    - ``resume``: its marker must hold ``expected`` (e.g. the dataset's fingerprint), else refused;
      kept (returns ``True``);
    - otherwise (a dead run's, not resumed): removed, and ``False``.
    """
    partial = Path(partial)
    if not os.path.lexists(partial):
        return False
    marker = read_marker(partial) if partial.is_dir() and not partial.is_symlink() else None
    if marker is None:
        raise DataError(
            partial,
            f"was not written by supportnet (no {MARKER} inside), so it is left alone; "
            "remove it yourself or choose another --out",
        )
    pid = marker.get("pid")
    if isinstance(pid, int) and pid != os.getpid() and _alive(pid, partial):
        raise DataError(partial, f"is being written by process {pid}; wait for it or stop it first")
    if not resume:
        shutil.rmtree(partial)
        return False
    for key, value in expected.items():
        if marker.get(key) != value:
            what = key.replace("_", " ")
            raise DataError(
                partial,
                f"was made with another {what} ({marker.get(key)}, now {value}); "
                "run without --resume to start again",
            )
    write_marker(partial, marker.get("command"), **{k: v for k, v in marker.items() if k not in _OWN})
    return True


_OWN = ("written_by", "command", "version", "time", "pid", "host")


# -- files ----------------------------------------------------------------------------------------


def _strict(value: object) -> object:
    """``value`` with numpy/torch scalars and arrays as Python values and NaN, ±inf as ``None``."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (str, bool, int)):
        return value
    if isinstance(value, dict):
        return {_key(k): _strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_strict(v) for v in value]
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if hasattr(value, "to_dict"):
        return _strict(value.to_dict())
    if hasattr(value, "tolist"):  # numpy and torch scalars and arrays
        return _strict(value.tolist())
    if isinstance(value, (set, frozenset)):
        return [_strict(v) for v in sorted(value, key=repr)]
    try:
        return _strict(float(value))  # e.g. Decimal
    except (TypeError, ValueError):
        raise TypeError(f"{type(value).__name__} is not JSON serialisable: {value!r}") from None


def _key(key: object) -> object:
    if isinstance(key, (str, int, float, bool)) or key is None:
        return key
    return key.item() if hasattr(key, "item") else str(key)


def write_json(path: Path, data: object) -> None:
    """Write ``data`` as strict JSON (RFC 8259): NaN and infinities become ``null``.

    ``null`` rather than a refusal: a statistic that has no value (the Pearson r of a constant
    map, an error without a reference) should not throw away a run's outputs, and ``null`` is the
    JSON for "no value", which every parser reads (Python's ``NaN`` is not JSON at all).
    """
    text = json.dumps(_strict(data), indent=2, allow_nan=False)
    Path(path).write_text(text + "\n")


def resolved_config(config: BaseModel) -> str:
    """The YAML a command saves beside its outputs: every key of ``config``, defaults resolved."""
    return yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False)


class _Stage(ProgressColumn):
    """The task's ``stage`` field (what a long item is doing now), where it has one."""

    def render(self, task: Task) -> Text:
        return Text(str(task.fields.get("stage", "")), style="dim")


class _LineProgress(Progress):
    """Off a terminal (a log file, CI) rich draws no bar, so a long command would print nothing for
    minutes: there the current stage and count are a line ``label: done/total, stage`` at most
    every :data:`LINE_EVERY_S` seconds, the first that long after the start (a user mistake found
    at once still ends in its one line), and the count once more at the end."""

    def __init__(self, label: str, *columns: ProgressColumn, console: Console) -> None:
        super().__init__(*columns, console=console, transient=True)
        self._label, self._said = label, time.monotonic()

    def _say(self, task_id: TaskID, finished: bool = False) -> None:
        if not finished and time.monotonic() - self._said < LINE_EVERY_S:
            return
        self._said = time.monotonic()
        task = self._tasks[task_id]
        total = f"/{task.total:g}" if task.total is not None else ""
        stage = task.fields.get("stage")
        line = f"{self._label}: {task.completed:g}{total}" + (f", {stage}" if stage and not finished else "")
        self.console.print(line, markup=False, highlight=False)

    def update(self, task_id: TaskID, **kwargs: object) -> None:
        super().update(task_id, **kwargs)
        self._say(task_id)

    def advance(self, task_id: TaskID, advance: float = 1) -> None:
        super().advance(task_id, advance)
        self._say(task_id, self._tasks[task_id].finished)


LINE_EVERY_S = 10.0
"""How often the progress is a line off a terminal (:class:`_LineProgress`)."""


def progress_bar(label: str, console: Console) -> Progress:
    """A transient bar ``label ━━━ done/total time-left stage`` on ``console`` (stderr for
    commands); ``progress.update(task, stage=...)`` says what the current item is doing. Off a
    terminal, lines instead (:class:`_LineProgress`)."""
    columns = (TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(), _Stage())
    if not console.is_terminal:
        return _LineProgress(label, *columns, console=console)
    return Progress(*columns, console=console, transient=True)
