"""`python -m stimuli render --cluster slurm` and `python -m analysis imagestats --cluster slurm`
on a real SLURM controller and node started on this machine (:mod:`tests.slurm_processes`):
worker jobs submitted through dask-jobqueue, one cancelled with `scancel` mid-render and
replaced, every image once. Fails (never skips) where SLURM cannot be started. Renders are 32 px at 36 spp."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time

import pandas as pd
import pytest

from stimuli import load_manifest, verify_manifest
from tests.dask_processes import REPO, kill

pytestmark = [pytest.mark.slurm, pytest.mark.slow]

N_IMAGES = 10
JOB = ["--cores", "1", "--memory", "1GiB", "--walltime", "00:10:00"]


def _job_history(slurm) -> str:
    """The controller's own lines on each job: submitted, started, ended, cancelled."""
    wanted = ("_slurm_rpc_submit_batch_job", "sched: Allocate", "_job_complete",
              "REQUEST_KILL_JOB")
    return "\n".join(line for line in slurm.controller_log().splitlines()
                     if any(w in line for w in wanted))


def _run_in_background(args, cwd, slurm, err_path, env=None):
    with open(err_path, "w") as err_file:
        return subprocess.Popen([sys.executable, "-m", *args], cwd=cwd,
                                env={**os.environ, **slurm.env, "PYTHONPATH": str(REPO),
                                     **(env or {})},
                                stdout=subprocess.PIPE, stderr=err_file, text=True,
                                start_new_session=True)


def test_a_render_on_slurm_survives_a_job_cancelled_mid_render(tmp_path, slurm):
    """One worker job of 1 core (`--jobs 1`: the run cannot finish unless the cancelled job is
    replaced); once the first EXR is logged, `scancel` it: the run says its worker left and its
    tasks go to the next to join, a job is submitted in its place, its worker renders the groups
    that were in flight and the rest; exit 0, every image exactly once; the controller's log shows
    both jobs submitted, the first killed, the second ended by itself (COMPLETED, exit 0) once
    the run retired its worker, and no job is left in the queue."""
    out = tmp_path / "r"
    log = out / "renders.csv"
    jobs_dir = tmp_path / "jobs"  # sbatch writes each job's slurm-<id>.out here
    jobs_dir.mkdir()
    err_path = tmp_path / "render.err"
    before = set(slurm.submitted())  # the cluster is the session's: other tests' jobs
    t0 = time.monotonic()
    proc = _run_in_background(
        ["stimuli", "render", "--set", "imagestats", "--limit", str(N_IMAGES), "--out", str(out),
         "--cluster", "slurm", *JOB, "--jobs", "1", "--size", "32", "--spp", "36",
         "--no-progress"], jobs_dir, slurm, err_path,
        # Dask replaces a lost job after this (default 15 s)
        env={"DASK_DISTRIBUTED__DEPLOY__LOST_WORKER_TIMEOUT": "1s"})
    try:
        deadline = time.monotonic() + 120
        while not (log.is_file() and len(log.read_text().splitlines()) >= 2):
            assert proc.poll() is None, err_path.read_text() + slurm.logs()
            assert time.monotonic() < deadline, "no EXR in 120 s\n" + slurm.logs()
            time.sleep(0.02)
        running = slurm.jobs(states="RUNNING")
        assert len(running) == 1, "one job renders\n" + _job_history(slurm)
        cancelled = running[0]
        slurm.command("scancel", cancelled)
        n_at_cancel = len(pd.read_csv(log))
        assert n_at_cancel < N_IMAGES, "the set was done before the cancel: proves nothing"
        stdout = proc.communicate(timeout=180)[0]
    finally:
        kill(proc)
    seconds = time.monotonic() - t0
    err = err_path.read_text()
    history = _job_history(slurm)
    print(f"render on SLURM: {seconds:.1f} s; job {cancelled} cancelled after {n_at_cancel} of "
          f"{N_IMAGES} EXRs\n{history}\n--- render's stderr\n{err}")
    assert proc.returncode == 0, err + slurm.logs()
    assert "Traceback" not in err, err
    # the replacement may join before the run's watch looks again: then it is "the 1 other(s)"
    assert "1 Dask worker(s) left" in err, err
    assert re.search(r"go to (the next worker to join|the 1 other\(s\) or the next to join)",
                     err), err
    assert err.count("1 Dask worker(s) joined (1 connected)") == 2, err  # the job, its replacement
    m = load_manifest(out)
    assert len(m) == N_IMAGES and m["stimulus_id"].is_unique
    assert verify_manifest(out, kinds=("png", "exr")) == []  # every file there, checksums hold
    assert all((out / p).is_file() for p in m["png_path"])
    assert pd.read_csv(log)["stimulus_id"].is_unique  # no EXR logged twice
    assert f'"rendered": {N_IMAGES}' in stdout
    submitted = [j for j in slurm.submitted() if j not in before]
    assert len(submitted) == 2 and submitted[0] == cancelled, history  # and one in its place
    replacement = submitted[1]
    assert f"REQUEST_KILL_JOB JobId={cancelled} " in history
    assert slurm.job_state(cancelled) == "CANCELLED"
    assert f"_job_complete: JobId={replacement} WEXITSTATUS 0" in history
    assert f"REQUEST_KILL_JOB JobId={replacement} " not in history  # it ended by itself
    assert slurm.job_state(replacement) == "COMPLETED", history
    assert slurm.jobs() == [], "the run left jobs in the queue\n" + history
    for j in submitted:  # each job's worker ran here and joined the run's scheduler
        assert re.search(r"Registered to:\s+tcp://", (jobs_dir / f"slurm-{j}.out").read_text())


def test_image_statistics_on_slurm_jobs(tmp_path, slurm, rng):
    """`analysis imagestats --cluster slurm`: one worker job measures a rendered folder (known
    images, known statistics) and ends by itself."""
    from analysis.imagestats import load_stats
    from tests.analysis.imagestats.renders import write_render_set
    from tests.analysis.imagestats.test_compute import _check_known

    folder = tmp_path / "r"
    params = write_render_set(folder, rng, n_images=8)
    out = tmp_path / "stats.parquet"
    before = set(slurm.submitted())
    err_path = tmp_path / "stats.err"
    proc = _run_in_background(
        ["analysis", "imagestats", str(folder), "--out", str(out), "--cluster", "slurm",
         "--cores", "1", "--memory", "2GiB", "--walltime", "00:10:00", "--jobs", "1",
         "--batch-size", "2", "--quiet", "--no-ps"], tmp_path, slurm, err_path)
    try:
        stdout = proc.communicate(timeout=180)[0]
    finally:
        kill(proc)
    err = err_path.read_text()
    history = _job_history(slurm)
    print(f"image statistics on SLURM:\n{history}\n--- stderr\n{err}")
    assert proc.returncode == 0, err + history
    assert "8 images in the manifest, 0 already done, 8 computed" in stdout, stdout + err
    _check_known(load_stats(out), params)
    jobs = [j for j in slurm.submitted() if j not in before]
    states = {j: slurm.job_state(j) for j in jobs}
    assert len(jobs) == 1 and states[jobs[0]] == "COMPLETED", f"{states}\n{history}"
    assert slurm.jobs() == []


_HOLDS_A_RESULT = """
from stimuli.dask_cluster import JobSpec, open_client
spec = JobSpec(system="slurm", cores=1, memory="1GiB", walltime="00:10:00", jobs=1)
with open_client(spec=spec) as (client, _):
    kept = client.submit(bytes, 1000)  # its result stays on the one worker while held here
    assert kept.result() == bytes(1000)
    print("held", flush=True)
"""


def test_a_worker_job_still_holding_a_result_ends_completed(tmp_path, slurm):
    """At the end of a run the client may still hold results that live only on a worker; Dask
    then refuses to retire that worker ("unique data could not be moved"), which the run's end
    took as "no job of ours ended" and cancelled the job. The run is over and its results
    kept, so the worker is closed all the same: its job ends COMPLETED, not CANCELLED."""
    before = set(slurm.submitted())
    err_path = tmp_path / "held.err"
    with open(err_path, "w") as err_file:
        proc = subprocess.Popen([sys.executable, "-c", _HOLDS_A_RESULT], cwd=tmp_path,
                                env={**os.environ, **slurm.env, "PYTHONPATH": str(REPO)},
                                stdout=subprocess.PIPE, stderr=err_file, text=True,
                                start_new_session=True)
    try:
        stdout = proc.communicate(timeout=180)[0]
    finally:
        kill(proc)
    err, history = err_path.read_text(), _job_history(slurm)
    print(f"a client holding a result:\n{history}\n--- stderr\n{err}")
    assert proc.returncode == 0 and "held" in stdout, err + history
    jobs = [j for j in slurm.submitted() if j not in before]
    states = {j: slurm.job_state(j) for j in jobs}
    assert len(jobs) == 1 and states[jobs[0]] == "COMPLETED", f"{states}\n{history}"
    assert slurm.jobs() == []
