"""Dask for the long runs (renders, image statistics): where the workers come from, and a run
that outlives them.

Three ways to get workers, one per command-line option:

* ``--workers N``: a ``LocalCluster`` on this machine (closed at the end);
* ``--scheduler tcp://host:8786``: a scheduler the lab started (``dask scheduler``) and workers
  started by hand on any machines (``dask worker tcp://host:8786``), joining and leaving at will;
* ``--cluster slurm|pbs|sge``: a batch system through dask-jobqueue (the Dask project's package
  for job queues): this process runs the scheduler and submits ``--jobs`` worker jobs of
  ``--cores``, ``--memory``, ``--walltime`` on ``--queue`` (defaults from the design's
  ``[cluster]``); jobs that end (walltime, pre-emption, ``scancel``) are replaced once Dask counts
  their worker as lost; when the run ends, SLURM jobs end by themselves (their workers retire:
  COMPLETED, exit 0), other jobs are cancelled. ``--dry-run`` prints the job script and submits
  nothing. A SLURM job is first tried with ``sbatch --test-only``; a refused job, one that can
  never start, and Ctrl-C (which cancels the jobs) end the run in one line
  (:mod:`stimuli.job_submission`). Tested on a real SLURM 22.05 (``tests/stimuli/test_slurm.py``); PBS and SGE only
  through their job scripts.

:func:`finished` drives the tasks: a worker that dies (killed, pre-empted) costs only its tasks in
flight, which the scheduler gives to the other workers or to the next one to join; a task that
outlived several workers (Dask's ``KilledWorker``) is submitted again; while no worker is
connected for ``no_worker_s`` seconds it says, once per such period, what to start, and waits.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shlex
import sys
import time
import weakref
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from stimuli.errors import ClusterError

__all__ = [
    "BATCH_SYSTEMS",
    "ClusterError",
    "JobSpec",
    "SchedulerLost",
    "add_cluster_arguments",
    "finished",
    "job_memory",
    "job_script",
    "job_spec_from",
    "open_client",
    "per_thread",
    "per_worker",
    "worker_command",
]

#: Batch systems ``--cluster`` takes, and their dask-jobqueue classes.
BATCH_SYSTEMS = {"slurm": "SLURMCluster", "pbs": "PBSCluster", "sge": "SGECluster"}
#: Seconds without any worker before the run says what to start (``--no-worker-timeout``).
NO_WORKER_S = 120.0
#: How often a task may be lost with its worker after Dask's own retries (3 workers) before the
#: run stops: a task that kills every worker it lands on is a bug, not a pre-emption.
MAX_RESUBMITS = 3
#: The least memory a worker job may ask for, bytes: a render worker (Python, Dask, Mitsuba) holds
#: about 0.43 GiB by itself (measured: peak RSS of a 32 px render), and Dask pauses a worker at
#: 80 % of its limit.
MIN_JOB_MEMORY_BYTES = 10**9
_REPO = Path(__file__).resolve().parents[1]
#: Client -> the JobWatch of its batch jobs, asked by :func:`finished` while no worker runs.
_JOB_WATCHES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


@dataclass(frozen=True)
class JobSpec:
    """One batch job = one Dask worker process whose threads use the job's cores (renders), or
    one process per core (``processes``; image statistics, whose NumPy/PyTorch work holds the GIL
    in parts).

    Attributes
    ----------
    system : str
        One of :data:`BATCH_SYSTEMS`.
    cores : int
        Cores per job (the worker's threads, and Dr.Jit's).
    memory : str
        Memory per job, e.g. ``"8GiB"``.
    walltime : str
        ``HH:MM:SS`` per job; the worker retires 5 minutes before it ends.
    queue : str
        Queue (SLURM partition); empty: the system's default.
    jobs : int
        Jobs kept running (a job that ends is replaced).
    account : str
        Account or project charged; empty: the user's default.
    extra : tuple of str
        More job directives, verbatim (e.g. ``"--gres=gpu:1"``, ``"-pe smp 4"``).
    processes : int
        Dask worker processes per job (the job's cores are shared among them).
    """

    system: str
    cores: int
    memory: str
    walltime: str
    queue: str = ""
    jobs: int = 1
    account: str = ""
    extra: tuple[str, ...] = ()
    processes: int = 1


def add_cluster_arguments(parser, where) -> None:
    """``--cluster`` (into the mutually exclusive group ``where``) and the job options."""
    where.add_argument("--cluster", choices=sorted(BATCH_SYSTEMS),
                       help="run the workers as batch jobs (dask-jobqueue); job size from "
                       "--cores/--memory/--walltime/--queue/--jobs or the design's [cluster]")
    g = parser.add_argument_group("batch jobs (--cluster)")
    g.add_argument("--cores", type=int, help="cores per job (design: cluster.cores)")
    g.add_argument("--memory", help="memory per job, e.g. 8GiB (design: cluster.memory)")
    g.add_argument("--walltime", help="HH:MM:SS per job (design: cluster.walltime)")
    g.add_argument("--queue", help="queue or SLURM partition (design: cluster.queue)")
    g.add_argument("--jobs", type=int, help="worker jobs kept running (design: cluster.jobs)")
    g.add_argument("--account", help="account charged (design: cluster.account)")
    g.add_argument("--job-extra", action="append", default=[], metavar="DIRECTIVE",
                   help="another job directive, verbatim (repeatable), e.g. --job-extra='-pe smp 4' on "
                   "SGE (with '=' when it starts with '-')")
    g.add_argument("--dry-run", action="store_true",
                   help="print the job script and submit nothing")
    parser.add_argument("--no-worker-timeout", type=float, default=NO_WORKER_S, metavar="S",
                        help="seconds without any worker before the run says what to start "
                        f"(it keeps waiting; default {NO_WORKER_S:g})")


def job_spec_from(args, design) -> JobSpec:
    """The job of ``--cluster``: each option from the command line, else the design's
    ``[cluster]``."""
    c = design.cluster

    def pick(name):
        value = getattr(args, name, None)
        return getattr(c, name) if value is None else value

    memory = job_memory(str(pick("memory")), "--memory" if getattr(args, "memory", None)
                        is not None else f"cluster.memory of {design.source}")
    spec = JobSpec(system=args.cluster, cores=int(pick("cores")), memory=memory,
                   walltime=str(pick("walltime")), queue=str(pick("queue")),
                   jobs=int(pick("jobs")), account=str(pick("account")),
                   extra=tuple(getattr(args, "job_extra", None) or ()))
    if spec.cores < 1 or spec.jobs < 1:
        raise ClusterError(f"--cores {spec.cores} / --jobs {spec.jobs}: use at least 1 each")
    if not re.fullmatch(r"(\d+-)?\d{1,3}:\d{2}:\d{2}", spec.walltime):
        raise ClusterError(f"--walltime {spec.walltime!r} is not HH:MM:SS (e.g. --walltime "
                           "04:00:00)")
    return spec


def job_memory(text: str, source: str = "--memory") -> str:
    """``text`` if it is an amount of memory a batch job can ask for (a number and a unit,
    ``"16GB"``, ``"8GiB"``, ``"500 MB"``), at least :data:`MIN_JOB_MEMORY_BYTES`.

    Raises
    ------
    ClusterError
        Naming ``source`` (``--memory`` or the design's ``cluster.memory``), the value and the fix:
        a bare number (dask-jobqueue would read ``16`` as 16 bytes and fail formatting it), an
        unknown unit, or too little for a worker.
    """
    from dask.utils import parse_bytes

    value = text.strip()
    match = re.fullmatch(r"(\d+(?:\.\d*)?|\.\d+)\s*([A-Za-z]*)", value)
    if match is None:
        raise ClusterError(f"{source} {text!r} is not an amount of memory: give a number and a "
                           "unit, e.g. 16GB or 8GiB")
    if not match.group(2):
        raise ClusterError(f"{source} {text}: give a unit, e.g. {match.group(1)}GB (a bare "
                           "number would be read as bytes)")
    try:
        n_bytes = parse_bytes(value)
    except ValueError:
        raise ClusterError(f"{source} {text!r}: unknown unit {match.group(2)!r}; use kB, MB, "
                           "GB, TB or KiB, MiB, GiB, TiB, e.g. 16GB") from None
    if n_bytes < MIN_JOB_MEMORY_BYTES:
        raise ClusterError(f"{source} {text}: a worker job needs at least 1GB (a render worker "
                           "holds about 0.45 GiB by itself, and Dask pauses it at 80 % of its "
                           "memory); give e.g. 8GiB")
    return value


def _seconds(walltime: str) -> int:
    days, _, hms = walltime.rpartition("-")
    h, m, s = (int(v) for v in hms.split(":"))
    return int(days or 0) * 86400 + h * 3600 + m * 60 + s


def _prologue() -> list[str]:
    """Shell lines before the worker starts: the project importable as here, the libLLVM here."""
    lines = [f"export PYTHONPATH={shlex.quote(str(_REPO))}${{PYTHONPATH:+:$PYTHONPATH}}",
             "export OMP_NUM_THREADS=1"]
    llvm = os.environ.get("DRJIT_LIBLLVM_PATH")
    if llvm:
        lines.append(f"export DRJIT_LIBLLVM_PATH=${{DRJIT_LIBLLVM_PATH:-{shlex.quote(llvm)}}}")
    return lines


def _jobqueue_cluster(spec: JobSpec):
    from stimuli.job_submission import import_jobqueue

    try:
        dask_jobqueue = import_jobqueue()
    except ImportError as exc:
        raise ClusterError(f"--cluster needs dask-jobqueue ({exc}); install the project "
                           "(`make venv`) or `.venv/bin/pip install dask-jobqueue`") from exc
    cls = getattr(dask_jobqueue, BATCH_SYSTEMS[spec.system])
    lifetime = _seconds(spec.walltime) - 300
    extra_args = (["--lifetime", f"{lifetime}s", "--lifetime-stagger", "60s"]
                  if lifetime >= 600 else [])
    kwargs = {"cores": spec.cores, "processes": spec.processes, "memory": spec.memory,
              "walltime": spec.walltime, "queue": spec.queue or None, "python": sys.executable,
              "job_script_prologue": _prologue(), "worker_extra_args": extra_args,
              "job_extra_directives": list(spec.extra), "job_name": "glossdepth-worker",
              "scheduler_options": {"dashboard_address": None},
              "silence_logs": logging.ERROR}
    if spec.account:
        kwargs["project" if spec.system == "sge" else "account"] = spec.account
    if spec.system == "sge":  # SGE takes memory as a resource; cores need the site's PE name
        kwargs["resource_spec"] = f"h_vmem={spec.memory}"
    return cls(**kwargs)


def job_script(spec: JobSpec) -> str:
    """The script each worker job runs (``--dry-run``); the scheduler address in it is that of
    a scheduler started only to write it."""
    with _jobqueue_cluster(spec) as cluster:
        return cluster.job_script()


def worker_command(address: str) -> str:
    """The command that starts a worker for ``address`` with this project's Python."""
    return f"{shlex.quote(sys.executable)} -m distributed.cli.dask_worker {address}"


@contextlib.contextmanager
def open_client(*, scheduler: str | None = None, spec: JobSpec | None = None,
                local: Callable | None = None):
    """Yield ``(client, what_to_start)``: a client on the scheduler at ``scheduler``, on a
    batch cluster of ``spec``, or on ``local()`` (a LocalCluster made by the caller); closed on
    exit. ``what_to_start`` is the advice printed while no worker is connected.
    """
    from distributed import Client

    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise ClusterError(
                f"cannot reach the Dask scheduler at {scheduler} ({exc}); start one (`dask "
                "scheduler`), then workers (`dask worker ADDRESS`), or leave out --scheduler"
            ) from exc
        advice = (f"start one on any machine that sees the output folder at the same path: "
                  f"`{worker_command(scheduler)}` (or `dask worker {scheduler}` in this "
                  "project's virtual environment)")
        with _quiet_client(), client:
            yield client, advice
        return
    if spec is not None:
        with _batch_client(spec) as (client, advice):
            yield client, advice
        return
    cluster = local()
    with _quiet_client(), cluster, Client(cluster) as client:
        yield client, "the local cluster lost its workers: stop with Ctrl-C and run again"


@contextlib.contextmanager
def _batch_client(spec: JobSpec):
    """A client on worker jobs of ``spec`` (see :func:`open_client`): a SLURM job is first
    tried with ``sbatch --test-only``; the run's :class:`~stimuli.job_submission.JobWatch`
    ends it when a job is refused or can never start; Ctrl-C cancels the jobs at once."""
    from distributed import Client

    from stimuli.job_submission import (
        JobWatch,
        cancel_jobs,
        check_slurm_job,
        end_jobs,
        forget_refused,
    )

    cluster = _jobqueue_cluster(spec)
    with contextlib.ExitStack() as stack:
        stack.enter_context(_quiet_client())
        stack.enter_context(cluster)
        if spec.system == "slurm":
            check_slurm_job(cluster.job_script())
        watch = stack.enter_context(JobWatch(cluster, spec.system).refusals())
        adaptive = cluster.adapt(minimum_jobs=spec.jobs, maximum_jobs=spec.jobs)
        queue = {"slurm": "squeue -u $USER", "pbs": "qstat -u $USER",
                 "sge": "qstat -u $USER"}[spec.system]
        advice = (f"{spec.jobs} worker job(s) were submitted to {spec.system.upper()} and none "
                  f"runs yet: check the queue (`{queue}`); stop with Ctrl-C (finished work is "
                  "kept) to change its options; `--dry-run` shows the job script")
        client = stack.enter_context(Client(cluster))
        _JOB_WATCHES[client] = watch
        try:
            yield client, advice
        except KeyboardInterrupt:
            cancel_jobs(cluster, adaptive, spec.system)
            raise
        except BaseException:
            forget_refused(cluster)
            end_jobs(cluster, client, adaptive, spec.system)
            raise
        else:
            end_jobs(cluster, client, adaptive, spec.system)


class _Watch:
    """Who is connected: says when workers leave or join, and when none is left for long."""

    def __init__(self, client, say, what_to_start: str, no_worker_s: float):
        self.client, self.say = client, say
        self.what_to_start, self.no_worker_s = what_to_start, no_worker_s
        self.nthreads = self._workers()
        self.workers = set(self.nthreads)
        self.alone_since = self.last_said = None

    def _workers(self) -> dict:
        try:
            return self.client.nthreads()
        except (OSError, TimeoutError) as exc:
            raise _gone(self.client, exc) from None

    def check(self, n_waiting: int) -> None:
        self.nthreads = self._workers()
        now, workers = time.monotonic(), set(self.nthreads)
        left, joined = self.workers - workers, workers - self.workers
        if left:
            where = (f"the {len(workers)} other(s) or the next to join" if workers
                     else "the next worker to join")
            self.say(f"{len(left)} Dask worker(s) left ({', '.join(sorted(left))}); their "
                     f"unfinished tasks go to {where}")
        if joined:
            self.say(f"{len(joined)} Dask worker(s) joined ({len(workers)} connected)")
        self.workers = workers
        if workers:
            self.alone_since = self.last_said = None
            return
        jobs = _JOB_WATCHES.get(self.client)
        if jobs is not None:
            jobs.check()  # a refused job, or one that can never start, ends the run
        self.alone_since = self.alone_since or now
        if now - self.alone_since >= self.no_worker_s and (
                self.last_said is None or now - self.last_said >= self.no_worker_s):
            self.say(f"no Dask worker connected for {now - self.alone_since:.0f} s, "
                     f"{n_waiting} task(s) waiting: {self.what_to_start}; the run goes on by "
                     "itself once one joins")
            self.last_said = now


class SchedulerLost(ClusterError):
    """The Dask scheduler went away mid-run (killed, its machine rebooted): the run cannot go
    on, and re-running the same command resumes it."""


@contextlib.contextmanager
def _quiet_client():
    """Dask's client logs "Couldn't gather keys" and, when the scheduler is lost, a chained
    traceback per reconnection attempt ("Failed to reconnect to scheduler"), also while the
    client closes: this module says these in words instead (:func:`_gone`)."""
    logger = logging.getLogger("distributed.client")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


def _gone(client, exc) -> SchedulerLost:
    return SchedulerLost(
        f"lost the Dask scheduler at {client.scheduler.address} ({type(exc).__name__}: it was "
        "stopped, killed or became unreachable); start it again (`dask scheduler`, and workers) "
        "and re-run the same command: it resumes, finished work is kept")


def per_thread(nthreads: dict) -> int:
    """Tasks in flight: two per worker thread (each thread has its next task at hand)."""
    return 2 * sum(nthreads.values())


def per_worker(nthreads: dict) -> int:
    """Tasks in flight: two per worker, whatever its threads (tasks that run one at a time in a
    process: renders)."""
    return 2 * len(nthreads)


def finished(client, submit: Callable, items: Iterable, *, what_to_start: str,
             no_worker_s: float = NO_WORKER_S, poll_s: float = 2.0,
             say: Callable[[str], None] | None = None,
             in_flight: Callable[[dict], int] = per_thread) -> Iterator:
    """Run ``submit(item)`` (a function returning a Dask future) for every item; yield each
    result as it finishes, in any order.

    Only ``in_flight(client.nthreads())`` tasks (at least 2) are on the cluster at a time, the
    rest are submitted as those finish: a worker never holds more work than it can start soon,
    so a worker that joins late gets its share and one that dies loses little.

    A task whose worker died is run again by the scheduler on another worker (Dask's own
    retries, ``distributed.scheduler.allowed-failures``); one lost with its workers more often
    (``KilledWorker``) is submitted again, up to :data:`MAX_RESUBMITS` times. Workers that leave
    or join are named through ``say`` (default: stderr); while none is connected for
    ``no_worker_s`` seconds, ``say`` gets ``what_to_start``, once per such period; the run waits.

    Raises
    ------
    ClusterError
        If a task was lost with its workers more than :data:`MAX_RESUBMITS` times after Dask's
        retries; :class:`SchedulerLost` if the scheduler went away (no Dask traceback). Any error
        the task itself raised is re-raised.
    """
    from concurrent.futures import CancelledError

    from distributed import wait
    from distributed.scheduler import KilledWorker

    say = say or (lambda m: print(m, file=sys.stderr, flush=True))
    waiting = deque(items)
    pending: dict = {}
    watch = _Watch(client, say, what_to_start, no_worker_s)

    def top_up() -> None:
        cap = max(2, in_flight(watch.nthreads))
        while waiting and len(pending) < cap:
            item = waiting.popleft()
            pending[submit(item)] = (item, 0)

    with _quiet_client():
        try:
            top_up()
        except (CancelledError, OSError) as exc:
            raise _gone(client, exc) from None
        while pending:
            try:
                done = wait(list(pending), timeout=poll_s, return_when="FIRST_COMPLETED").done
            except TimeoutError:
                done = set()
            except (CancelledError, OSError) as exc:  # the scheduler went away mid-wait
                raise _gone(client, exc) from None
            for future in done:
                item, lost = pending.pop(future)
                try:
                    # bounded: a result held by a worker that dies now is computed again,
                    # which waits for a worker; meanwhile this loop must go on watching
                    result = future.result(timeout=poll_s)
                except TimeoutError:
                    pending[future] = (item, lost)
                    continue
                except KilledWorker as exc:
                    if lost >= MAX_RESUBMITS:
                        raise ClusterError(
                            f"a task was lost with its workers {lost + 1} times, each after "
                            f"Dask's own retries ({exc}); a worker may be running out of memory "
                            "on it: read the worker logs, give workers more memory (--memory), "
                            "and run the same command again (finished work is kept)") from None
                    pending[submit(item)] = (item, lost + 1)
                    continue
                except CancelledError as exc:
                    raise _gone(client, exc) from None
                future.release()
                yield result
            watch.check(len(pending) + len(waiting))
            try:
                top_up()
            except (CancelledError, OSError) as exc:
                raise _gone(client, exc) from None
