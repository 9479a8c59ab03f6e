"""What wrote a report: the command, the source's commit, the date and the host, for the header
of every report a command writes (a number without them cannot be traced back or rerun)."""

from __future__ import annotations

import os
import platform
import shlex
import socket
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import NamedTuple

SOURCE = Path(__file__).resolve().parent.parent  #: the checkout (or site-packages) the package runs from


class Provenance(NamedTuple):
    """Who wrote a report: ``command`` as typed (shell-quoted), ``commit`` of the source tree,
    ``date`` (UTC, ISO 8601, seconds) and ``host`` (name, processor, CPUs, platform)."""

    command: str
    commit: str
    date: str
    host: str

    def markdown(self) -> list[str]:
        """The report header's lines (a Markdown list)."""
        return [
            f"- command: `{self.command}`",
            f"- commit: {self.commit}",
            f"- date: {self.date}",
            f"- host: {self.host}",
        ]


def command_line(argv: list[str] | None = None, program: str | None = None) -> str:
    """``program`` and ``argv`` shell-quoted (default: this process's command line, sys.argv;
    ``python -m package`` for a package's __main__.py)."""
    if argv is None:
        script = Path(sys.argv[0])
        program = f"python -m {script.parent.name}" if script.name == "__main__.py" else script.name or "python"
        return " ".join([program, shlex.join(sys.argv[1:])]).strip()
    return shlex.join([program or "python", *argv])


def source_commit(root: Path = SOURCE) -> str:
    """The git commit of the source tree ``root`` (12 hex digits, "+ uncommitted changes" when
    tracked files differ from it), or the package version where ``root`` is no git checkout."""
    from fourwis import __version__

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", "-C", str(root), *args], capture_output=True, text=True, timeout=20, check=True
        ).stdout.strip()

    if not (root / ".git").exists():
        return f"none (fourwis {__version__}, not a git checkout)"
    try:
        commit = git("rev-parse", "--short=12", "HEAD")
        dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return f"unknown (fourwis {__version__}; git could not read {root})"
    return commit + (" + uncommitted changes" if dirty else "")


def cpu_model() -> str:
    """The processor's model name (Linux: /proc/cpuinfo), else the machine type."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def provenance(command: str | None = None) -> Provenance:
    """The header of a report written now by ``command`` (default: this process's command line)."""
    return Provenance(
        command if command is not None else command_line(),
        source_commit(),
        datetime.now(UTC).isoformat(timespec="seconds"),
        f"{socket.gethostname()} ({cpu_model()}, {os.cpu_count()} CPUs, {platform.platform()})",
    )
