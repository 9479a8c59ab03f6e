"""Atomic file output: a report, table or checkpoint is either whole or absent, never half-written."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def check_writable(out: str | Path, kind: str = "directory", name: str = "--out") -> Path:
    """``out`` as a Path if it can be written as a ``kind`` ("directory" or "file"): not the
    other kind already, in a directory that exists or can be created (its nearest existing
    ancestor a writable directory); else ValueError naming ``name`` and the path. Jobs call it
    before they run, so a bad path does not cost the results."""
    if not str(out).strip():
        raise ValueError(f"{name} must not be empty")
    out = Path(out)
    if kind == "directory" and out.exists() and not out.is_dir():
        raise ValueError(f"{name} must be a directory, but {out} is a file")
    if kind == "file" and out.is_dir():
        raise ValueError(f"{name} must be a file, but {out} is a directory")
    ancestor = out if kind == "directory" and out.is_dir() else out.parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not (ancestor.is_dir() and os.access(ancestor, os.W_OK)):
        raise ValueError(f"{name} {out} cannot be written: {ancestor} is not a writable directory")
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
