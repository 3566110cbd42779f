"""Several processes of one scenario on one bus, started and stopped together.

A scenario script runs inside the namespace (:func:`hil.namespace.run_scenario`) and starts its
processes here, so all of them share the namespace and its bus::

    with Processes(workdir / "logs") as procs:
        procs.dtid("vehicle", "vehicle", "--config", str(config), "--speedup", "20")
        procs.dtid("worker", "worker", "--config", str(config))
        procs.dtid("acquire", "acquire", "--config", str(config))
        procs.wait("acquire", timeout=100)
        procs.signal("worker", signal.SIGKILL)   # fault cases: kill, restart, ...

Each process writes its standard output and error to ``NAME.out`` and ``NAME.err`` in the log
folder (no pipes that could fill up and block it). On leaving the ``with`` block every process
still running gets SIGTERM, and SIGKILL after a grace period.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType

from hil.namespace import child_env


class Processes:
    """Named child processes with their output in files.

    Parameters
    ----------
    log_dir
        Folder for ``NAME.out`` and ``NAME.err`` (made if missing).
    env
        Variables added to the environment of every process (the repository is always on
        ``PYTHONPATH``, so ``python -m dtid.cli`` runs the work tree).
    """

    def __init__(self, log_dir: Path, env: Mapping[str, str] | None = None) -> None:
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.env = child_env(env)
        self.running: dict[str, subprocess.Popen[bytes]] = {}

    def __enter__(self) -> Processes:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.stop_all()

    def start(
        self, name: str, argv: Sequence[str], *, stdin: bool = False
    ) -> subprocess.Popen[bytes]:
        """Start ``argv`` as ``name``; with ``stdin`` its standard input is a pipe (see
        :meth:`send_line`), else /dev/null. A name may be reused once its process has ended.
        """
        old = self.running.get(name)
        if old is not None and old.poll() is None:
            raise RuntimeError(f"process {name!r} is still running")
        with (
            open(self.log_dir / f"{name}.out", "ab") as out,
            open(self.log_dir / f"{name}.err", "ab") as err,
        ):
            process = subprocess.Popen(
                list(argv),
                stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
                stdout=out,
                stderr=err,
                env=self.env,
            )
        self.running[name] = process
        return process

    def dtid(self, name: str, *args: str, stdin: bool = False) -> subprocess.Popen[bytes]:
        """Start ``dtid ARGS...`` from the work tree as ``name``."""
        return self.start(name, [sys.executable, "-m", "dtid.cli", *args], stdin=stdin)

    def python(self, name: str, *args: str, stdin: bool = False) -> subprocess.Popen[bytes]:
        """Start ``python ARGS...`` (a script or ``-m module``) as ``name``."""
        return self.start(name, [sys.executable, *args], stdin=stdin)

    def send_line(self, name: str, line: str) -> None:
        """Write one line to the standard input of ``name`` (started with ``stdin=True``)."""
        pipe = self.running[name].stdin
        if pipe is None:
            raise RuntimeError(f"process {name!r} was started without stdin=True")
        pipe.write(line.encode() + b"\n")
        pipe.flush()

    def output(self, name: str) -> str:
        """Everything ``name`` has written to its standard output so far."""
        return (self.log_dir / f"{name}.out").read_text(errors="replace")

    def errors(self, name: str) -> str:
        """Everything ``name`` has written to its standard error so far."""
        return (self.log_dir / f"{name}.err").read_text(errors="replace")

    def wait_for_line(self, name: str, text: str, timeout: float) -> str:
        """Wait until a line of the standard output of ``name`` contains ``text``; return it.

        Raises
        ------
        TimeoutError
            After ``timeout`` s, or at once when the process has ended without that line.
        """
        deadline = time.monotonic() + timeout
        while True:
            ended = self.running[name].poll() is not None
            for line in self.output(name).splitlines():
                if text in line:
                    return line
            if ended or time.monotonic() > deadline:
                state = "ended" if ended else f"still running after {timeout:g} s"
                raise TimeoutError(
                    f"{name} {state} without printing {text!r}; stderr:\n{self.errors(name)}"
                )
            time.sleep(0.01)

    def wait(self, name: str, timeout: float) -> int:
        """Wait for ``name`` to end; return its exit status (TimeoutError after ``timeout`` s)."""
        try:
            return self.running[name].wait(timeout)
        except subprocess.TimeoutExpired:
            raise TimeoutError(f"{name} still running after {timeout:g} s") from None

    def signal(self, name: str, sig: int = signal.SIGTERM) -> None:
        """Send ``sig`` to ``name`` if it is still running."""
        process = self.running[name]
        if process.poll() is None:
            os.kill(process.pid, sig)

    def stop_all(self, grace: float = 5.0) -> dict[str, int]:
        """SIGTERM every running process, SIGKILL what is left after ``grace`` s; exit statuses."""
        for process in self.running.values():
            if process.poll() is None:
                process.terminate()
        deadline = time.monotonic() + grace
        for process in self.running.values():
            try:
                process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            if process.stdin is not None:
                process.stdin.close()
        return {name: process.returncode for name, process in self.running.items()}
