"""Child processes of the launchers (``demo``, ``up``): started, drained, reported, stopped.

A child's stderr is read continuously by a thread of ours: to the console (each line
prefixed with the child's name), to a log file when the run has an output directory, and
into a short memory of recent lines for the failure report. A pipe that nobody reads fills
after 64 KiB and then blocks the child on its next write: a vehicle that logs a warning
per bad request would stop flying after a few thousand requests. Nothing here may block on
a closed console: lines that cannot be written there are dropped and counted, the log file
keeps them all.
"""

from __future__ import annotations

import contextlib
import ctypes
import shlex
import signal
import subprocess
import sys
import threading
from collections import deque
from pathlib import Path
from typing import IO

from heli_common.port_handoff import HeldPorts

TAIL_LINES = 200  # kept in memory for the failure report


def die_with_parent() -> None:
    """Child-side: get SIGTERM if this (the parent) process dies, however it dies (Linux)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


class Child:
    """One child process whose stderr is always drained (see the module docstring)."""

    def __init__(
        self,
        name: str,
        cmd: list[str],
        log_path: Path | None = None,
        echo: IO[str] | None = None,
        cwd: Path | None = None,
        handoff: tuple[HeldPorts, tuple[int, ...]] | None = None,
    ) -> None:
        self.name = name
        self.cmd = cmd
        self.log_path = log_path
        self._echo = echo
        self._tail: deque[str] = deque(maxlen=TAIL_LINES)
        self._lock = threading.Lock()
        self.lines = 0
        self.echo_dropped = 0
        self._log: IO[str] | None = None
        if log_path is not None:
            log_path.parent.mkdir(parents=True, exist_ok=True)
            self._log = log_path.open("w", encoding="utf-8", errors="replace")
            # a quiet run leaves nothing else here (the processes log warnings and errors
            # only): say what ran, so an empty-looking log is not mistaken for a lost one
            one_line = shlex.join(cmd).replace("\n", "\\n")  # a `python -c` script has newlines
            self._log.write(f"# {name}: {one_line}\n# its warnings and errors follow (none: a "
                            "clean run); -v on its command line logs more\n")  # fmt: skip
            self._log.flush()
        # the ports the launcher holds for this child: inherited, adopted by its bind
        held, ports = handoff if handoff is not None else (HeldPorts(), ())
        self.proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, preexec_fn=die_with_parent, cwd=cwd,
                                     env=held.env(ports), pass_fds=held.fds(ports))  # fmt: skip
        self._reader = threading.Thread(target=self._drain, name=f"drain-{name}", daemon=True)
        self._reader.start()

    # -- the drain ----------------------------------------------------------------------
    def _drain(self) -> None:
        stream = self.proc.stderr
        assert stream is not None
        for raw in iter(stream.readline, b""):
            line = raw.decode(errors="replace").rstrip("\r\n")
            with self._lock:
                self._tail.append(line)
                self.lines += 1
            if self._log is not None:
                self._log.write(line + "\n")
                self._log.flush()
            if self._echo is not None:
                try:
                    self._echo.write(f"[{self.name}] {line}\n")
                    self._echo.flush()
                except (OSError, ValueError):  # closed or broken console: the log keeps it
                    self.echo_dropped += 1
        stream.close()
        if self._log is not None:
            try:
                ended = f"ended with exit status {self.proc.wait(5.0)}"
            except subprocess.TimeoutExpired:
                ended = "closed its stderr"
            self._log.write(f"# {self.name} {ended} ({self.lines} lines above)\n")
            self._log.close()

    def join_output(self, timeout_s: float = 5.0) -> None:
        """Wait until everything the (exited) child wrote has been read."""
        self._reader.join(timeout_s)

    def output(self) -> str:
        """The most recent stderr lines (all of them if fewer than TAIL_LINES)."""
        with self._lock:
            return "\n".join(self._tail)

    def last_error_line(self) -> str:
        """The child's own last non-empty stderr line, or how it ended."""
        if self.proc.poll() is not None:
            self.join_output(1.0)
        with self._lock:
            for line in reversed(self._tail):
                if line.strip():
                    return line.strip()
        return describe_exit(self.proc.returncode)

    # -- the process --------------------------------------------------------------------
    @property
    def returncode(self) -> int | None:
        return self.proc.returncode

    def poll(self) -> int | None:
        return self.proc.poll()

    def wait(self, timeout: float | None = None) -> int:
        return self.proc.wait(timeout)

    def send_signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()

    def stop(self, grace_s: float = 10.0, resend: bool = True) -> None:
        """SIGTERM (unless already sent), then SIGKILL after ``grace_s``; output drained."""
        if resend:
            self.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.join_output()


def describe_exit(returncode: int | None) -> str:
    if returncode is None:
        return "still running"
    if returncode < 0:
        with contextlib.suppress(ValueError):
            return f"killed by {signal.Signals(-returncode).name}"
        return f"killed by signal {-returncode}"
    return f"exit code {returncode}"


def spawn(
    cmd: list[str], name: str | None = None, log_path: Path | None = None, echo: bool = False,
    cwd: Path | None = None,
    handoff: tuple[HeldPorts, tuple[int, ...]] | None = None,
) -> Child:
    """Start a child that dies with us and whose stderr is drained (echoed if ``echo``), in
    ``cwd`` (None: ours); ``handoff``: the held ports it binds, handed down to it
    (:mod:`heli_common.port_handoff`)."""
    return Child(name or Path(cmd[2] if len(cmd) > 2 else cmd[0]).name, cmd, log_path,
                 sys.stderr if echo else None, cwd, handoff)  # fmt: skip


def stop_all(children: list[Child]) -> None:
    """SIGTERM to all at once (they stop in parallel), then wait for each."""
    for c in children:
        c.send_signal(signal.SIGTERM)
    for c in children:
        c.stop(resend=False)
