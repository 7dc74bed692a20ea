"""Whether a batch system takes the worker jobs of ``--cluster``, said in one line.

dask-jobqueue submits worker jobs from its event loop: a job that ``sbatch`` refuses (a partition
that does not exist, more memory or cores than any node, no SLURM configuration) was a tornado
traceback, and the run then waited for workers forever, saying every period that jobs "were
submitted"; a stale configuration (a controller that no longer answers) waited forever too; and
importing dask-jobqueue replaced Python's Ctrl-C handler with ``sys.exit()``, so a Ctrl-C ended
the run with exit status 0 and no word. Here:

* :func:`import_jobqueue` imports dask-jobqueue and gives Ctrl-C back to Python
  (``KeyboardInterrupt``);
* :func:`check_slurm_job` asks ``sbatch --test-only`` whether the job script would be taken,
  before anything is submitted: a refusal is one line (sbatch's reason and the fix), a
  configuration that names no file or a controller that does not answer in
  :data:`SBATCH_TIMEOUT_S` is said too;
* :class:`JobWatch` is asked by the run while no worker is connected: a submission refused
  during the run (a replacement job) ends it with sbatch's reason, and a job SLURM keeps pending
  for a reason that never resolves by itself (:data:`NEVER_REASONS`, read with ``squeue``
  every :data:`PENDING_CHECK_S` seconds) ends it within a minute.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from stimuli.errors import ClusterError

__all__ = ["NEVER_REASONS", "JobWatch", "cancel_jobs", "check_slurm_job", "end_jobs",
           "forget_refused", "import_jobqueue", "refusal_line", "submitted_job_ids"]

#: Seconds ``sbatch --test-only`` may take (a stale controller address fails after ~20 s).
SBATCH_TIMEOUT_S = 45.0
#: Seconds between two ``squeue`` reads of the pending jobs' reasons.
PENDING_CHECK_S = 10.0
#: squeue reasons of a pending job that no waiting resolves: the job asks for more than the
#: partition, account or QOS allows (SLURM's "Job Reason Codes").
NEVER_REASONS = frozenset({
    "PartitionTimeLimit", "PartitionNodeLimit", "PartitionConfig", "BadConstraints",
    "InvalidAccount", "InvalidQOS", "AccountNotAllowed", "QOSNotAllowed",
    "QOSMaxWallDurationPerJobLimit", "AssocMaxWallDurationPerJobLimit",
    "QOSMaxCpuPerJobLimit", "QOSMaxMemoryPerJob", "QOSMaxNodePerJobLimit",
    "DependencyNeverSatisfied"})
#: What to do, by words in sbatch's refusal.
_FIXES = {
    "partition": ("check --queue (or the design's cluster.queue): `sinfo -s` lists the "
                  "partitions"),
    "node configuration is not available": (
        "no node has that many cores and that much memory: `sinfo -N -o '%N %c %m'` lists each "
        "node's cores and memory (MB); ask for less with --cores/--memory"),
    "account": ("check --account (or the design's cluster.account): `sacctmgr show assoc "
                "user=$USER` lists yours"),
    "qos": "check the job's QOS (--job-extra): `sacctmgr show qos` lists them",
    "time limit": "ask for less --walltime: `sinfo -o '%P %l'` lists each partition's limit",
    "contact slurm controller": (
        "the SLURM controller named in the configuration does not answer: a stale "
        "configuration, or not a submit host? `scontrol ping` checks it"),
    "configuration file": ("no SLURM configuration: set SLURM_CONF to the cluster's slurm.conf "
                           "or run on a submit host"),
}


def import_jobqueue():
    """``dask_jobqueue``, imported without its SIGINT handler (``sys.exit()``, exit status 0):
    Ctrl-C stays Python's ``KeyboardInterrupt``, so the run cancels its jobs and says so."""
    before = signal.getsignal(signal.SIGINT)
    try:
        import dask_jobqueue
    finally:
        with contextlib.suppress(ValueError):  # not the main thread: nothing was replaced
            signal.signal(signal.SIGINT, before)
    return dask_jobqueue


def refusal_line(stderr: str, *, what: str = "sbatch", system: str = "SLURM") -> str:
    """A submission command's refusal (``stderr``; ``what`` ran it) as one line: its reasons,
    then the fix."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    reasons = []
    for line in lines:
        for prefix in ("sbatch: error: ", "sbatch: fatal: ", "allocation failure: "):
            line = line.removeprefix(prefix)
        if "retrying in" in line or line in reasons:
            continue
        reasons.append(line)
    said = "; ".join(reasons) or "no reason given"
    low = said.lower()
    fix = next((f for words, f in _FIXES.items() if words in low),
               "`--dry-run` shows the job script it was asked to take")
    return f"{system} refused the worker job ({what}: {said}); {fix}. Nothing was submitted"


def check_slurm_job(script: str) -> None:
    """Ask ``sbatch --test-only`` whether SLURM would take the worker job ``script``.

    Raises
    ------
    ClusterError
        The configuration file ``SLURM_CONF`` names does not exist, ``sbatch`` is not installed,
        refuses the job (:func:`refusal_line`) or does not answer in :data:`SBATCH_TIMEOUT_S`.
    """

    conf = os.environ.get("SLURM_CONF")
    if conf and not Path(conf).is_file():
        raise ClusterError(f"SLURM_CONF={conf}: no such file, so SLURM has no configuration; "
                           "set SLURM_CONF to the cluster's slurm.conf (or unset it on a "
                           "submit host). Nothing was submitted")
    with tempfile.NamedTemporaryFile("w", suffix=".sh", prefix="glossdepth-job-") as fh:
        fh.write(script)
        fh.flush()
        try:
            done = subprocess.run(["sbatch", "--test-only", fh.name], capture_output=True,
                                  text=True, timeout=SBATCH_TIMEOUT_S, check=False)
        except FileNotFoundError:
            raise ClusterError("--cluster slurm: sbatch is not installed here; run on a SLURM "
                               "submit host") from None
        except subprocess.TimeoutExpired:
            raise ClusterError(
                f"sbatch did not answer in {SBATCH_TIMEOUT_S:g} s (SLURM_CONF="
                f"{conf or 'the default'}): the SLURM controller does not answer; a stale "
                "configuration, or not a submit host? `scontrol ping` checks it. Nothing was "
                "submitted") from None
    if done.returncode != 0:
        raise ClusterError(refusal_line(done.stderr, what="sbatch --test-only"))


def submitted_job_ids(cluster) -> list[str]:
    """The batch ids of the jobs a dask-jobqueue cluster submitted and still holds."""
    return [str(job.job_id) for job in list(cluster.workers.values())
            if getattr(job, "job_id", None)]


class JobWatch:
    """What the batch system says of this run's jobs while no worker is connected.

    Installed with :meth:`refusals` around the cluster's life (it takes dask-jobqueue's failed
    submissions off tornado's log); :meth:`check` raises once one was refused or a job pends
    for one of :data:`NEVER_REASONS`.
    """

    def __init__(self, cluster, system: str):
        self.cluster, self.system = cluster, system
        self.refused: list[str] = []
        self.last_check = time.monotonic()

    @contextlib.contextmanager
    def refusals(self):
        """Record every submission the batch system refuses (the cluster's new jobs are of a
        class that records it), and keep the traceback the event loop logs of one off stderr
        (a failed job start at a run's start reaches tornado's log, a replacement's is a
        warning of Dask's adaptive scaling, silenced)."""
        refused = self.refused
        base = self.cluster.new_spec["cls"]

        class RecordedJob(base):
            async def _submit_job(self, script_filename):
                try:
                    return await super()._submit_job(script_filename)
                except RuntimeError as exc:
                    refused.append(str(exc).split("stderr:", 1)[-1])
                    raise

        self.cluster.new_spec["cls"] = RecordedJob
        logger = logging.getLogger("tornado.application")

        def keep(record: logging.LogRecord) -> bool:
            exc = record.exc_info[1] if record.exc_info else None
            return not (isinstance(exc, RuntimeError)
                        and "Command exited with non-zero" in str(exc))

        logger.addFilter(keep)
        try:
            yield self
        finally:
            logger.removeFilter(keep)
            self.cluster.new_spec["cls"] = base

    def check(self) -> None:
        """Raise :class:`~stimuli.dask_cluster.ClusterError` if a job was refused or can never
        start; the run then ends (its jobs are cancelled, finished work is kept)."""
    
        if self.refused:
            line = refusal_line(self.refused[0], system=self.system.upper(),
                                what="sbatch" if self.system == "slurm" else "qsub")
            line = line.replace(". Nothing was submitted", "")
            raise ClusterError(f"{line}; finished work is kept: fix the options and run the "
                               "same command again")
        now = time.monotonic()
        if self.system != "slurm" or now - self.last_check < PENDING_CHECK_S:
            return
        self.last_check = now
        ids = submitted_job_ids(self.cluster)
        if not ids:
            return
        with contextlib.suppress(OSError, subprocess.TimeoutExpired):
            listed = subprocess.run(["squeue", "-h", "-o", "%i %T %r", "-j", ",".join(ids)],
                                    capture_output=True, text=True, timeout=10, check=False)
            for line in listed.stdout.splitlines():
                job, state, reason = (line.split(None, 2) + ["", ""])[:3]
                if state == "PENDING" and reason.split(",")[0] in NEVER_REASONS:
                    raise ClusterError(
                        f"SLURM keeps worker job {job} pending for reason {reason}: it can "
                        "never start as asked (more --walltime, --cores or --memory than the "
                        "partition, account or QOS allows; `scontrol show job "
                        f"{job}` says more); its jobs are cancelled, finished work is kept: "
                        "fix the options and run the same command again")


def forget_refused(cluster) -> None:
    """Mark the jobs the batch system refused (no job id) as failed and drop them from
    ``cluster``: closing it asserts each job it made closed or failed, and a refused one stays
    "created" (an AssertionError after the run's own error)."""
    from distributed.core import Status

    for job in list(getattr(cluster, "_created", ())):
        if not getattr(job, "job_id", None) and job.status == Status.created:
            job.status = Status.failed
    for key, job in list(cluster.workers.items()):
        if not getattr(job, "job_id", None):
            del cluster.workers[key]


def cancel_jobs(cluster, adaptive, system: str) -> None:
    """Ctrl-C: no job is replaced and every job this run submitted is cancelled now (closing
    the cluster cancels them, ``scancel``), a second Ctrl-C meanwhile ignored; says which."""
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        adaptive.stop()
        ids = submitted_job_ids(cluster)
        if ids:
            print(f"cancelling the {len(ids)} worker job(s) this run submitted to "
                  f"{system.upper()} ({', '.join(ids)})", file=sys.stderr, flush=True)
        cluster.close()
    finally:
        signal.signal(signal.SIGINT, before)


def _close_workers(addresses: list[str], dask_scheduler=None) -> None:
    """On the scheduler: ask each worker at ``addresses`` to shut down (its job then ends)."""
    for address in addresses:
        dask_scheduler.close_worker(address)


def end_jobs(cluster, client, adaptive, system: str, wait_s: float = 60.0) -> None:
    """Let SLURM worker jobs end by themselves, so that they end COMPLETED (exit 0) in its
    records rather than CANCELLED: no job is replaced any more, each worker is retired (or,
    where it still holds a result the client refers to, closed) and its process exits, and the
    run waits (up to ``wait_s``) until those jobs have left the queue; any still there then is
    cancelled (``scancel``), as closing the cluster cancels the jobs that never ran a worker. Other systems: every job is cancelled on closing, as before (their queue
    commands are untested here)."""
    from concurrent.futures import CancelledError

    adaptive.stop()
    if system != "slurm":
        return
    try:
        retired = client.retire_workers(close_workers=True)
        # Dask refuses to retire a worker holding a result the client still refers to ("unique
        # data could not be moved"): the run is over and its results kept, so close it anyway
        kept = {addr: info for addr, info in client.scheduler_info()["workers"].items()
                if addr not in retired}
        if kept:
            client.run_on_scheduler(_close_workers, list(kept))
    except (OSError, TimeoutError, CancelledError):
        return
    names = {str(info.get("name")) for info in [*retired.values(), *kept.values()]}
    ending = []
    for key, job in list(cluster.workers.items()):  # a job's workers are named KEY or KEY-i
        if getattr(job, "job_id", None) and any(n == str(key) or n.startswith(f"{key}-")
                                                for n in names):
            del cluster.workers[key]  # neither Dask's lost-worker timer nor closing cancels it
            ending.append(str(job.job_id))
    if not ending:
        return
    import subprocess

    deadline = time.monotonic() + wait_s
    queued = ending
    with contextlib.suppress(OSError, subprocess.TimeoutExpired):
        while queued and time.monotonic() < deadline:
            time.sleep(0.2)
            listed = subprocess.run(["squeue", "-h", "-o", "%i", "-j", ",".join(queued)],
                                    capture_output=True, text=True, timeout=10, check=False)
            # squeue refuses ids it no longer knows (exit 1): all of them ended
            queued = listed.stdout.split() if listed.returncode == 0 else []
        if queued:
            subprocess.run(["scancel", *queued], capture_output=True, timeout=10, check=False)
