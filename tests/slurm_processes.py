"""A real SLURM cluster of one node on this machine, as the tests' batch scheduler.

Debian's ``slurm-wlm`` (22.05) and ``munge`` (the Makefile's DEB_PACKAGES) started without systemd
or cgroups, as the user who runs the tests (root is not needed: ``SlurmUser`` and ``SlurmdUser``
are that user, and jobs run as that user): ``munged`` with a key of its own, ``slurmctld`` and one
``slurmd`` (node ``localhost`` at 127.0.0.1 with this machine's CPUs), their configuration, state,
logs and pid files in one folder under the temporary directory (``munged`` refuses a socket whose
folder others cannot traverse, so not under pytest's private ``tmp_path``), on free ports. Process
tracking by ``/proc`` (``proctrack/linuxproc``), no task plugin, no job accounting (so no
``sacct``: jobs are followed through ``squeue``, ``scontrol show job`` and the controller's log).

:func:`local_slurm` starts it, waits until the node is idle and, on exit, cancels every job left
and stops the daemons by their pid files (SIGTERM, then SIGKILL).
"""

from __future__ import annotations

import contextlib
import os
import pwd
import re
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

#: The programs the cluster needs, and the Debian package each comes from.
PROGRAMS = {"munged": "munge", "slurmctld": "slurmctld", "slurmd": "slurmd",
            "sbatch": "slurm-client", "squeue": "slurm-client", "scancel": "slurm-client",
            "scontrol": "slurm-client", "sinfo": "slurm-client"}
#: Daemons in the order they start; they stop in the reverse order.
DAEMONS = ("munged", "slurmctld", "slurmd")
_SEARCH_PATH = os.pathsep.join([os.environ.get("PATH", ""), "/usr/sbin", "/sbin", "/usr/bin"])


class SlurmError(RuntimeError):
    """The local SLURM cluster could not be started or did not answer; the message says why."""


def _program(name: str) -> str:
    path = shutil.which(name, path=_SEARCH_PATH)
    if path is None:
        raise SlurmError(f"{name} is not installed: install Debian's slurm-wlm and munge "
                         "(`sudo apt-get install slurm-wlm munge`; `make test` installs them, "
                         "they are in the Makefile's DEB_PACKAGES)")
    return path


def _user() -> str:
    return pwd.getpwuid(os.getuid()).pw_name


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _memory_mib() -> int:
    """What slurmd will find (MemTotal), MiB."""
    text = Path("/proc/meminfo").read_text()
    return int(re.search(r"MemTotal:\s+(\d+) kB", text).group(1)) // 1024


def slurm_conf(folder: Path, *, user: str, ctld_port: int, slurmd_port: int, cpus: int,
               memory_mib: int) -> str:
    """The ``slurm.conf`` of a one-node cluster whose every file lies in ``folder``."""
    return f"""\
ClusterName=glossdepth-test
SlurmctldHost=localhost(127.0.0.1)
SlurmUser={user}
SlurmdUser={user}
SlurmctldPort={ctld_port}
SlurmdPort={slurmd_port}
AuthType=auth/munge
AuthInfo=socket={folder / "munge.socket"}
StateSaveLocation={folder / "state"}
SlurmdSpoolDir={folder / "spool"}
SlurmctldPidFile={folder / "slurmctld.pid"}
SlurmdPidFile={folder / "slurmd.pid"}
SlurmctldLogFile={folder / "slurmctld.log"}
SlurmdLogFile={folder / "slurmd.log"}
SlurmctldDebug=info
SlurmdDebug=info
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
SwitchType=switch/none
MpiDefault=none
ReturnToService=2
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
MinJobAge=600
NodeName=localhost NodeAddr=127.0.0.1 CPUs={cpus} RealMemory={memory_mib} State=UNKNOWN
PartitionName=local Nodes=localhost Default=YES MaxTime=INFINITE State=UP
"""


@dataclass
class LocalSlurm:
    """A running one-node cluster: ``env`` (``SLURM_CONF``) makes ``sbatch``, ``squeue`` and
    dask-jobqueue use it."""

    folder: Path
    env: dict

    def command(self, name: str, *args: str, timeout_s: float = 30) -> str:
        """Run a SLURM client command on this cluster; its stdout."""
        done = subprocess.run([_program(name), *args], env={**os.environ, **self.env},
                              capture_output=True, text=True, timeout=timeout_s, check=False)
        if done.returncode != 0:
            raise SlurmError(f"{name} {' '.join(args)}: exit {done.returncode}: "
                             f"{done.stderr.strip()}")
        return done.stdout

    def jobs(self, *, states: str = "PENDING,CONFIGURING,RUNNING,COMPLETING,SUSPENDED") -> list[str]:
        """Ids of the jobs not yet ended (``states``: squeue's ``-t``, e.g. ``RUNNING``)."""
        return self.command("squeue", "-h", "-o", "%i", "-t", states).split()

    def job_state(self, job_id: str) -> str:
        """``JobState`` of a job (kept MinJobAge = 600 s after it ends), e.g. ``COMPLETED``."""
        text = self.command("scontrol", "show", "job", job_id)
        return re.search(r"JobState=(\S+)", text).group(1)

    def submitted(self) -> list[str]:
        """Ids of every job the controller accepted, from its log, in order."""
        return re.findall(r"_slurm_rpc_submit_batch_job: JobId=(\d+)", self.controller_log())

    def controller_log(self) -> str:
        path = self.folder / "slurmctld.log"
        return path.read_text(errors="replace") if path.is_file() else ""

    def logs(self, tail_chars: int = 3000) -> str:
        """The daemons' logs, each's last ``tail_chars`` characters (for failure messages)."""
        return "\n".join(f"--- {f.name}\n{f.read_text(errors='replace')[-tail_chars:]}"
                         for f in sorted(self.folder.glob("*.log")))


def _alive(pid: int) -> bool:
    """Running (a zombie, whose parent has not reaped it, counts as ended)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in status


def _stop_daemon(pid_file: Path, wait_s: float = 10) -> None:
    try:
        pid = int(pid_file.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return
    for sig in (signal.SIGTERM, signal.SIGKILL):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, sig)
        deadline = time.monotonic() + wait_s
        while _alive(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        if not _alive(pid):
            return


def _start(folder: Path) -> LocalSlurm:
    for name in PROGRAMS:
        _program(name)
    (folder / "state").mkdir()
    (folder / "spool").mkdir()
    key = folder / "munge.key"
    key.write_bytes(os.urandom(128))
    key.chmod(0o600)
    done = subprocess.run(
        [_program("munged"), f"--socket={folder / 'munge.socket'}", f"--key-file={key}",
         f"--pid-file={folder / 'munged.pid'}", f"--log-file={folder / 'munged.log'}",
         f"--seed-file={folder / 'munged.seed'}"], capture_output=True, text=True, timeout=30,
        check=False)
    if done.returncode != 0:
        raise SlurmError(f"munged did not start (exit {done.returncode}): {done.stderr.strip()}")
    conf = folder / "slurm.conf"
    conf.write_text(slurm_conf(folder, user=_user(), ctld_port=_free_port(),
                               slurmd_port=_free_port(), cpus=os.cpu_count() or 1,
                               memory_mib=int(0.9 * _memory_mib())))
    slurm = LocalSlurm(folder, {"SLURM_CONF": str(conf)})
    for daemon, args in (("slurmctld", ["-i"]), ("slurmd", ["-N", "localhost"])):
        done = subprocess.run([_program(daemon), "-f", str(conf), *args], capture_output=True,
                              text=True, timeout=30, env={**os.environ, **slurm.env},
                              check=False)
        if done.returncode != 0:
            raise SlurmError(f"{daemon} did not start (exit {done.returncode}): "
                             f"{done.stderr.strip()}\n{slurm.logs()}")
    deadline = time.monotonic() + 30
    state = ""
    while time.monotonic() < deadline:
        with contextlib.suppress(SlurmError, subprocess.TimeoutExpired):
            state = slurm.command("sinfo", "-h", "-o", "%t", timeout_s=5).strip()
        if state == "idle":
            return slurm
        time.sleep(0.1)
    raise SlurmError(f"the node did not become idle in 30 s (state {state!r})\n{slurm.logs()}")


def _stop(slurm: LocalSlurm) -> None:
    """Cancel the jobs left (their job steps outlive slurmd), then stop the daemons."""
    with contextlib.suppress(SlurmError, subprocess.TimeoutExpired):
        if slurm.jobs():
            slurm.command("scancel", "-u", _user())
            deadline = time.monotonic() + 20
            while slurm.jobs() and time.monotonic() < deadline:
                time.sleep(0.2)
    for daemon in reversed(DAEMONS):
        _stop_daemon(slurm.folder / f"{daemon}.pid")


@contextlib.contextmanager
def local_slurm():
    """Yield a :class:`LocalSlurm` whose node is idle; stop it and remove its folder on exit.

    Raises
    ------
    SlurmError
        If a program is missing or a daemon does not start (with the daemons' logs).
    """
    folder = Path(tempfile.mkdtemp(prefix="glossdepth-slurm-"))
    folder.chmod(0o755)  # munged: its socket's folder must be traversable by all
    slurm = LocalSlurm(folder, {"SLURM_CONF": str(folder / "slurm.conf")})
    try:
        slurm = _start(folder)
        yield slurm
    finally:
        _stop(slurm)
        shutil.rmtree(folder, ignore_errors=True)
