"""`python -m stimuli render --scheduler` on real `dask scheduler` / `dask worker` processes as a
lab starts them (loopback, free ports, two threads per worker), a worker killed mid-render, and
`--cluster slurm|pbs|sge --dry-run`'s job scripts. Renders are 32 px at 4 spp."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pandas as pd
import pytest

from stimuli import load_manifest, verify_manifest
from stimuli.__main__ import main
from tests.dask_processes import REPO, dask_processes, kill

TINY = ["--size", "32", "--spp", "4", "--no-progress"]


def _once_each(out, n):
    m = load_manifest(out)
    assert len(m) == n and m["stimulus_id"].is_unique
    assert verify_manifest(out, kinds=("png", "exr")) == []
    assert all((out / p).is_file() for p in m["png_path"])
    assert not list(out.rglob(".*tmp*"))


@pytest.mark.slow
def test_a_two_thread_dask_worker_renders_a_set(tmp_path, capsys):
    """`dask worker ADDRESS` starts one thread per core (two here): two tasks set Mitsuba up at
    once in one process ("module 'mitsuba' has no attribute 'variants'" before the lock)."""
    with dask_processes(tmp_path / "dask") as dask:
        dask.start_worker(nthreads=2)
        dask.wait_workers(1)
        out = tmp_path / "r"
        rc = main(["render", "--set", "preview", "--out", str(out), "--scheduler", dask.address,
                   *TINY])
        err = capsys.readouterr().err
        assert rc == 0, err + dask.logs()
    _once_each(out, 8)
    assert "plan: 8 images to render (0 already done)" in err
    assert "on the workers seen (1 machine(s), 2 cores)" in err
    assert "with added machines like these (2 cores each): +1:" in err


@pytest.mark.slow
def test_a_killed_worker_costs_only_its_images_and_the_run_finishes(tmp_path):
    """SIGKILL a worker (and its nanny) mid-render, as a batch system pre-empts a job: the run
    says what to start, waits, and finishes on a new worker: exit 0, no traceback, each stimulus
    once in the manifest, every PNG there."""
    out = tmp_path / "r"
    log = out / "renders.csv"
    with dask_processes(tmp_path / "dask") as dask:
        first = dask.start_worker(nthreads=2)
        dask.wait_workers(1)
        err_path = tmp_path / "render.err"
        with open(err_path, "w") as err_file:
            proc = subprocess.Popen(
                [sys.executable, "-m", "stimuli", "render", "--set", "experiment",
                 "--filter", "illumination=indoor", "--filter", "gloss_level=2,10",
                 "--out", str(out), "--scheduler", dask.address, "--no-worker-timeout", "1",
                 *TINY], cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)},
                stdout=subprocess.PIPE, stderr=err_file, text=True, start_new_session=True)
        try:
            deadline = time.monotonic() + 120
            while not (log.is_file() and len(log.read_text().splitlines()) >= 2):
                assert proc.poll() is None, err_path.read_text()
                assert time.monotonic() < deadline, "no group rendered in 120 s\n" + dask.logs()
                time.sleep(0.02)
            kill(first)
            n_at_kill = len(pd.read_csv(log))
            assert n_at_kill < 18, "the set was done before the kill: the test proves nothing"
            while "no Dask worker connected" not in err_path.read_text():
                assert proc.poll() is None, err_path.read_text()
                assert time.monotonic() < deadline + 60, "no message while no worker was left"
                time.sleep(0.1)
            dask.start_worker(nthreads=2)
            proc.communicate(timeout=180)
        finally:
            kill(proc)
    err = err_path.read_text()
    assert proc.returncode == 0, err + dask.logs()
    assert "Traceback" not in err, err
    assert f"dask worker {dask.address}" in err  # what to start
    assert "1 Dask worker(s) left (tcp://127.0.0.1:" in err and "worker(s) joined" in err
    _once_each(out, 18)
    renders = pd.read_csv(log)
    assert renders["stimulus_id"].is_unique  # finished EXRs were not rendered again


@pytest.mark.slow
def test_a_killed_scheduler_is_said_in_words_and_the_finished_light_fields_are_listed(tmp_path):
    """SIGKILL the `dask scheduler` once the first light field's EXRs are all logged: the run
    ends with one line naming what happened and the fix (re-run: it resumes), no chained Dask
    traceback, and a manifest listing the finished light field (before: a FuturesCancelledError
    traceback and no manifest); the same command then finishes the set, each image once."""
    from stimuli.sets import apply_filters, parse_filters, stimulus_set
    from studydesign import load_design

    out = tmp_path / "r"
    log = out / "renders.csv"
    select = ["--set", "experiment", "--filter", "gloss_level=2,10"]
    table = apply_filters(stimulus_set(load_design(), "experiment"),
                          parse_filters(["gloss_level=2,10"]))
    first = table["light_field"].iloc[0]
    first_ids = set(table.loc[table["light_field"] == first, "stimulus_id"])
    slow = [*select, "--out", str(out), "--size", "32", "--spp", "36", "--no-progress"]
    with dask_processes(tmp_path / "dask") as dask:
        dask.start_worker(nthreads=2)
        dask.wait_workers(1)
        err_path = tmp_path / "render.err"
        with open(err_path, "w") as err_file:
            proc = subprocess.Popen(
                [sys.executable, "-m", "stimuli", "render", *slow, "--scheduler", dask.address],
                cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, stdout=subprocess.PIPE,
                stderr=err_file, text=True, start_new_session=True)
        try:
            deadline = time.monotonic() + 120
            while not (log.is_file() and first_ids <= set(pd.read_csv(log)["stimulus_id"])):
                assert proc.poll() is None, err_path.read_text()
                assert time.monotonic() < deadline, "first light field not rendered in 120 s"
                time.sleep(0.02)
            kill(dask.procs[0])  # the scheduler
            n_at_kill = len(pd.read_csv(log))
            assert n_at_kill < len(table), "the set was done before the kill: proves nothing"
            proc.communicate(timeout=120)
        finally:
            kill(proc)
    err = err_path.read_text()
    assert proc.returncode == 1, err
    assert "Traceback" not in err and "During handling" not in err, err
    assert f"error: lost the Dask scheduler at {dask.address}" in err, err
    assert "re-run the same command" in err and "it resumes" in err, err
    listed = load_manifest(out)
    assert set(listed["stimulus_id"]) == first_ids, err  # the finished light field, no other
    assert verify_manifest(out, kinds=("png", "exr")) == []
    assert main(["render", *slow, "--workers", "0"]) == 0  # the same command, resumed here
    _once_each(out, len(table))
    assert pd.read_csv(log)["stimulus_id"].is_unique


@pytest.mark.parametrize("system, directives", [
    ("slurm", ["#SBATCH -p lab", "#SBATCH --cpus-per-task=8", "#SBATCH --mem=16G",
               "#SBATCH -t 12:00:00", "#SBATCH -A vision", "#SBATCH --gres=tmp:1"]),
    ("pbs", ["#PBS -q lab", "#PBS -l select=1:ncpus=8:mem=", "#PBS -l walltime=12:00:00",
             "#PBS -A vision", "#PBS --gres=tmp:1"]),
    ("sge", ["#$ -q lab", "#$ -l h_rt=12:00:00", "#$ -l h_vmem=16GiB", "#$ -P vision",
             "#$ --gres=tmp:1"]),
])
def test_cluster_dry_run_prints_the_job_script(tmp_path, capsys, system, directives):
    rc = main(["render", "--set", "imagestats", "--out", str(tmp_path / "r"), "--cluster", system,
               "--cores", "8", "--memory", "16GiB", "--walltime", "12:00:00", "--queue", "lab",
               "--account", "vision", "--job-extra=--gres=tmp:1", "--dry-run"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    script = captured.out
    assert script.startswith("#!")
    for d in directives:
        assert d in script, (d, script)
    worker = next(line for line in script.splitlines() if "dask_worker" in line)
    # the venv's Python, one worker process with the job's cores, retiring before the walltime
    assert worker.startswith(f"{sys.executable} -m distributed.cli.dask_worker tcp://")
    assert "--nthreads 8" in worker and "--lifetime 42900s" in worker
    assert f"export PYTHONPATH={REPO}" in script
    assert not (tmp_path / "r").exists()  # nothing rendered, nothing submitted


def test_cluster_job_size_comes_from_the_design(tmp_path, capsys):
    from studydesign import default_design_path

    design = tmp_path / "design.toml"
    text = default_design_path().read_text()
    design.write_text(text.replace('walltime = "04:00:00"', 'walltime = "1-00:00:00"')
                      .replace('queue = ""', 'queue = "render"'))
    rc = main(["--design", str(design), "render", "--set", "preview", "--out",
               str(tmp_path / "r"), "--cluster", "slurm", "--dry-run"])
    script = capsys.readouterr().out
    assert rc == 0
    assert "#SBATCH -p render" in script and "#SBATCH -t 1-00:00:00" in script
    assert "#SBATCH --cpus-per-task=4" in script  # [cluster] cores of the shipped design
    rc = main(["render", "--set", "preview", "--out", str(tmp_path / "r"), "--cluster", "slurm",
               "--walltime", "4h", "--dry-run"])
    assert rc == 1 and "--walltime '4h' is not HH:MM:SS" in capsys.readouterr().err


@pytest.mark.parametrize("memory, says", [
    ("16", "--memory 16: give a unit, e.g. 16GB"),
    ("0GiB", "--memory 0GiB: a worker job needs at least 1GB"),
    ("16k", "--memory 16k: a worker job needs at least 1GB"),
    ("16XB", "--memory '16XB': unknown unit 'XB'"),
    ("=-1GB", "--memory '-1GB' is not an amount of memory"),
])
def test_job_memory_without_a_unit_or_too_small_is_refused(tmp_path, capsys, memory, says):
    """`--memory 16` was a TypeError inside dask-jobqueue ("not all arguments converted during
    string formatting"); `0GiB` the same."""
    option = f"--memory{memory}" if memory.startswith("=") else ["--memory", memory]
    rc = main(["render", "--set", "preview", "--out", str(tmp_path / "r"), "--cluster", "slurm",
               "--dry-run", *([option] if isinstance(option, str) else option)])
    err = capsys.readouterr().err
    assert rc == 1 and says in err, err
    assert "Traceback" not in err and not (tmp_path / "r").exists()


def test_job_memory_of_the_design_without_a_unit_is_refused_naming_the_design(tmp_path, capsys):
    from analysis.imagestats.__main__ import main as imagestats_main
    from studydesign import default_design_path

    design = tmp_path / "design.toml"
    design.write_text(default_design_path().read_text().replace('memory = "8GiB"',
                                                                'memory = "16"'))
    rc = main(["--design", str(design), "render", "--set", "preview", "--out",
               str(tmp_path / "r"), "--cluster", "slurm", "--dry-run"])
    err = capsys.readouterr().err
    assert rc == 1 and f"cluster.memory of {design} 16: give a unit, e.g. 16GB" in err, err
    rc = imagestats_main([str(tmp_path), "--out", str(tmp_path / "s.parquet"), "--cluster",
                          "slurm", "--memory", "0GiB", "--dry-run"])
    err = capsys.readouterr().err
    assert rc == 1 and "--memory 0GiB: a worker job needs at least 1GB" in err, err


def _dies_first(marker: str, times: int) -> int:
    """Kill the worker process running it, the first ``times`` calls (counted in a file)."""
    from pathlib import Path

    path = Path(marker)
    n = int(path.read_text()) if path.exists() else 0
    path.write_text(str(n + 1))
    if n < times:
        os._exit(1)
    return n


@pytest.mark.parametrize("deaths, survives", [(1, True), (9, False)])
def test_a_task_lost_with_its_workers_is_submitted_again_then_given_up(tmp_path, deaths,
                                                                       survives):
    """Dask gives a task up (KilledWorker) after its workers died `allowed-failures` + 1 times
    (0 here, so at the first); the run submits it again, MAX_RESUBMITS times, then stops with a
    message naming the likely cause."""
    import dask
    from distributed import Client, LocalCluster

    from stimuli.dask_cluster import MAX_RESUBMITS, ClusterError, finished

    marker = str(tmp_path / "calls")
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}), \
            LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                         dashboard_address=None, silence_logs=50) as cluster, \
            Client(cluster) as client:
        run = finished(client, lambda k: client.submit(_dies_first, marker, deaths, pure=False),
                       [0], what_to_start="-")
        if survives:
            assert list(run) == [deaths]
        else:
            with pytest.raises(ClusterError, match="give workers more memory"):
                list(run)
            assert int((tmp_path / "calls").read_text()) == MAX_RESUBMITS + 1


def test_the_clients_libllvm_is_used_only_where_the_worker_has_none(tmp_path, monkeypatch):
    from stimuli.mitsuba_env import use_llvm_hint

    lib = tmp_path / "libLLVM.so.19.1"
    lib.write_bytes(b"")
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    use_llvm_hint(str(tmp_path / "absent.so"))  # not a file on this machine: left to the search
    assert "DRJIT_LIBLLVM_PATH" not in os.environ
    use_llvm_hint(str(lib))
    assert os.environ["DRJIT_LIBLLVM_PATH"] == str(lib)
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/the/workers/own.so")
    use_llvm_hint(str(lib))
    assert os.environ["DRJIT_LIBLLVM_PATH"] == "/the/workers/own.so"


def test_the_plan_of_the_full_set_matches_the_measured_44_hours(design):
    """58,564 images at 256 px and the design's spp took about 44 h on one 2-core machine."""
    from stimuli.runplan import plan_text
    from stimuli.sets import stimulus_set

    table = stimulus_set(design, "imagestats")
    measured_at = (24, 24, 25, 30, 30, 35, 36, 42, 48, 56, 80)  # the design's spp back then
    spp = [measured_at[g - 1] for g in table["gloss_level"]]
    text = plan_text(len(table), 0, 256, spp, {"lab-pc": 2})
    assert "plan: 58564 images to render (0 already done), 256 px" in text
    hours = float(text.split("2 cores): ")[1].split(" h")[0])
    assert 40 <= hours <= 48
    plus_one = float(text.split("+1: ")[1].split(" h")[0])
    assert plus_one == pytest.approx(hours / 2, abs=0.06)  # a second machine halves the time


@pytest.mark.parametrize("rule, cap", [("per_worker", 2), ("per_thread", 6)])
def test_only_a_few_tasks_per_worker_are_on_the_cluster_at_once(rule, cap):
    """A worker with many threads that renders one group at a time must not hold every group
    (a late worker would get none, a lost one would lose them all)."""
    from distributed import Client, LocalCluster

    from stimuli import dask_cluster

    seen = {"submitted": 0, "done": 0, "most": 0}

    with LocalCluster(n_workers=1, threads_per_worker=3, processes=False,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        def submit(i):
            seen["submitted"] += 1
            seen["most"] = max(seen["most"], seen["submitted"] - seen["done"])
            return client.submit(time.sleep, 0.01, key=f"sleep-{i}")

        for _ in dask_cluster.finished(client, submit, range(20), what_to_start="-",
                                       in_flight=getattr(dask_cluster, rule)):
            seen["done"] += 1
    assert seen["done"] == 20 and seen["most"] == cap
