"""``cgvq-study serve`` in a child process, for programs that drive a whole study around a
server (the demo, the server benchmark, the tests): started and waited for until it listens,
then stopped (SIGINT) or killed (SIGKILL, as a crash would).

It runs the command line, not this package, so the child is exactly what an experimenter
starts; only the standard library is used.
"""

from __future__ import annotations

import queue
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

READY_PREFIX = "serving study"
"""The line ``cgvq-study serve`` prints once it listens: ``serving study ID at URL``."""


@dataclass
class ServeProcess:
    """One ``cgvq-study serve STUDY --host 127.0.0.1 --port PORT ARGS...`` child."""

    study: Path
    args: list[str] = field(default_factory=list)
    port: int = 0
    """0: any free port (read back from the ready line)."""
    env: dict[str, str] | None = None
    cwd: Path | None = None
    url: str = ""
    proc: subprocess.Popen | None = None
    output: list[str] = field(default_factory=list)

    def start(self, timeout: float = 90.0) -> ServeProcess:
        """Start the child and wait for its ready line; RuntimeError if it exits or is late."""
        cmd = [sys.executable, "-m", "cgvq_cli.study_cli", "serve", str(self.study), "--host",
               "127.0.0.1", "--port", str(self.port), *self.args]
        self.proc = subprocess.Popen(cmd, env=self.env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, cwd=self.cwd)
        lines: queue.Queue[str | None] = queue.Queue()

        def pump() -> None:
            assert self.proc is not None and self.proc.stdout is not None
            for line in self.proc.stdout:
                self.output.append(line)
                lines.put(line)
            lines.put(None)

        threading.Thread(target=pump, daemon=True).start()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = lines.get(timeout=max(deadline - time.monotonic(), 0.1))
            except queue.Empty:
                break
            if line is None:
                raise RuntimeError("serve exited: " + "".join(self.output)[-2000:])
            if line.startswith(READY_PREFIX):
                self.url = line.rsplit(" at ", 1)[1].strip()
                self.port = int(self.url.rsplit(":", 1)[1])
                return self
        self.kill()
        raise RuntimeError("serve did not start in time: " + "".join(self.output)[-2000:])

    def kill(self) -> None:
        """SIGKILL, as a crash of the server's machine would."""
        if self.alive:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(timeout=30)

    def stop(self, timeout: float = 60.0) -> None:
        """SIGINT (a clean shutdown), killed if it takes longer than ``timeout``."""
        if self.alive:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.kill()

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None
