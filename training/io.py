"""Atomic file output: a report, table or checkpoint is either whole or absent, never
half-written; a command's folder of files (report, CSV, plots) holds its old set or its new one,
never a mix (:func:`staged_output`)."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path


def check_writable(out: str | Path, kind: str = "directory", name: str = "--out") -> Path:
    """``out`` as a Path once it is known to be writable as a ``kind`` ("directory" or "file"):
    not the other kind already, and its folder (``out`` itself, or a file's parent) created and
    a probe file made in it and removed; else ValueError naming ``name``, the path and the
    reason. Jobs call it before they run, so a bad path does not cost the results. (Creating is
    the test: ``os.access`` says yes to root on a read-only or virtual file system such as /proc.)"""
    if not str(out).strip():
        raise ValueError(f"{name} must not be empty")
    out = Path(out)
    try:
        if kind == "directory" and out.exists() and not out.is_dir():
            raise ValueError(f"{name} must be a directory, but {out} is a file")
        if kind == "file" and out.is_dir():
            raise ValueError(f"{name} must be a file, but {out} is a directory")
        folder = out if kind == "directory" else out.parent
        ancestor = folder
        while not ancestor.exists():
            ancestor = ancestor.parent
        if not ancestor.is_dir():
            raise ValueError(f"{name} {out} cannot be written: {ancestor} is not a writable directory")
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".fourwis-probe-")
        os.close(fd)
        os.unlink(probe)
    except OSError as err:  # (a name too long, no permission, a read-only or virtual file system)
        raise ValueError(f"{name} {out} cannot be written: {err.strerror or err}") from None
    return out


def atomic_write(path: str | Path, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then rename it into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        write(Path(tmp))
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual permissions
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def atomic_write_json(path: str | Path, data, default=None) -> str:
    """Write ``data`` as indented JSON (with a final newline) to ``path`` atomically; returns the
    text. ``default``: as json.dumps's, for values JSON cannot hold."""
    text = json.dumps(data, indent=2, default=default) + "\n"
    atomic_write_text(path, text)
    return text


STAGING_PREFIX = ".fourwis-staging-"  #: a command's staging folder inside its output folder
MANIFEST = ".fourwis-set.json"  #: the names of the set of files a command last swapped into its folder
#: the signals held back while a set is swapped in (SIGKILL cannot be)
DEFERRED_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """Hold Ctrl-C (SIGINT), SIGTERM and SIGHUP back while the block runs and deliver them after
    it (Python's handlers, or the default action, as installed before); a no-op outside the main
    thread, where Python cannot install handlers. Why: a swap of files that an interrupt cut in
    half would leave a mix of two sets."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []

    def hold(signum: int, frame) -> None:
        caught.append(signum)

    previous = {signum: signal.signal(signum, hold) for signum in DEFERRED_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)
        for signum in dict.fromkeys(caught):  # once each, in the order they came
            signal.raise_signal(signum)


@contextlib.contextmanager
def staged_output(out: str | Path) -> Iterator[Path]:
    """A staging folder inside ``out`` in which a command writes its whole set of files; when
    the block ends without an exception the set is swapped into ``out`` with interrupts held
    back (:func:`signals_deferred`): each file replaces its namesake, the files of the previous
    set (listed in ``out``'s :data:`MANIFEST`) that the new one lacks are deleted, and the
    manifest is rewritten. An exception (Ctrl-C during the runs or the plots) discards the
    staging folder, leaving the old set as it was. Files in ``out`` that no fourwis set wrote
    stay. Only SIGKILL or a crash during the swap (milliseconds) could leave a mix."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(dir=out, prefix=STAGING_PREFIX))
    try:
        yield stage
        with signals_deferred():
            _swap_in(stage, out)
    finally:
        with signals_deferred():
            shutil.rmtree(stage, ignore_errors=True)


def _previous_set(out: Path) -> list[str]:
    """The file names the manifest in ``out`` lists (none without a readable one); names that
    are not plain file names in ``out`` are ignored, so that a damaged manifest deletes nothing
    outside the set."""
    try:
        names = json.loads((out / MANIFEST).read_text())["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    if not isinstance(names, list):
        return []
    return [n for n in names if isinstance(n, str) and n and Path(n).name == n and not n.startswith(".")]


def _swap_in(stage: Path, out: Path) -> None:
    """Move the staged files into ``out`` (:func:`staged_output`)."""
    new = sorted(p.name for p in stage.iterdir() if not p.name.startswith("."))
    for name in new:
        os.replace(stage / name, out / name)
    for name in sorted(set(_previous_set(out)) - set(new)):
        stale = out / name
        if stale.is_file() or stale.is_symlink():
            stale.unlink()
    atomic_write_json(out / MANIFEST, {"files": new})


def pyplot():
    """matplotlib's pyplot on the file-only Agg backend (the reports' plots), or an ImportError
    naming the extra that installs it."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ModuleNotFoundError as err:  # optional dependency (a broken install raises its own error)
        raise ModuleNotFoundError("plots need matplotlib: pip install 'fourwis[plots]'") from err
    return plt
