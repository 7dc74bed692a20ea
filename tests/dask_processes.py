"""Real Dask processes on loopback, as a lab starts them: ``dask scheduler`` and ``dask worker``.

The scheduler takes a free port (``--port 0``; its address is read from its scheduler file);
workers get this checkout on ``PYTHONPATH`` and no ``DRJIT_LIBLLVM_PATH`` of their own (the run
ships it). Every process runs in its own session, is bounded in time and is killed with its
children on exit.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DASK = str(Path(sys.executable).with_name("dask"))


def worker_env() -> dict:
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    return env | {"PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}


def kill(proc: subprocess.Popen, sig=signal.SIGKILL, wait_s: float = 30) -> None:
    """End ``proc`` and its children (its session)."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=wait_s)


class DaskProcesses:
    """A ``dask scheduler`` on 127.0.0.1 and the ``dask worker`` processes started on it."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.procs: list[subprocess.Popen] = []
        self.address = ""

    def _start(self, args: list[str], log: str) -> subprocess.Popen:
        with open(self.folder / log, "ab") as fh:
            proc = subprocess.Popen([DASK, *args], env=worker_env(), cwd=self.folder,
                                    stdout=fh, stderr=subprocess.STDOUT, start_new_session=True)
        self.procs.append(proc)
        return proc

    def start_scheduler(self, timeout_s: float = 60) -> str:
        sfile = self.folder / "scheduler.json"
        proc = self._start(["scheduler", "--host", "127.0.0.1", "--port", "0",
                            "--no-dashboard", "--scheduler-file", str(sfile), "--idle-timeout", "300s"],
                           "scheduler.log")
        deadline = time.monotonic() + timeout_s
        while not sfile.is_file() or not sfile.read_text().strip():
            assert proc.poll() is None, (self.folder / "scheduler.log").read_text()
            assert time.monotonic() < deadline, "dask scheduler did not start in time"
            time.sleep(0.1)
        self.address = json.loads(sfile.read_text())["address"]
        return self.address

    def start_worker(self, nthreads: int = 2) -> subprocess.Popen:
        """``dask worker ADDRESS`` with a nanny (the default) and ``nthreads`` threads."""
        n = sum(1 for p in self.procs[1:])
        return self._start(["worker", self.address, "--nthreads", str(nthreads),
                            "--no-dashboard", "--host", "127.0.0.1", "--death-timeout", "60",
                            "--local-directory", str(self.folder / "work")],
                           f"worker{n}.log")

    def wait_workers(self, n: int, timeout_s: float = 90) -> None:
        from distributed import Client

        with Client(self.address, timeout="30s") as client:
            client.wait_for_workers(n, timeout=timeout_s)

    def logs(self) -> str:
        return "\n".join(f"--- {f.name}\n{f.read_text(errors='replace')[-3000:]}"
                         for f in sorted(self.folder.glob("*.log")))

    def close(self) -> None:
        for proc in reversed(self.procs):
            kill(proc, signal.SIGTERM, wait_s=10)
            kill(proc)


@contextlib.contextmanager
def dask_processes(folder: Path):
    folder.mkdir(parents=True, exist_ok=True)
    procs = DaskProcesses(folder)
    try:
        procs.start_scheduler()
        yield procs
    finally:
        procs.close()
