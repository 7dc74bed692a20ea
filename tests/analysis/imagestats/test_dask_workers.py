"""`python -m analysis imagestats --scheduler` on real `dask scheduler` / `dask worker` processes
(loopback, free ports, two threads per worker): a worker killed mid-run and a new one started;
`--cluster slurm --dry-run`."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from analysis.imagestats import load_stats
from analysis.imagestats.__main__ import main
from tests.analysis.imagestats.renders import write_render_set
from tests.analysis.imagestats.test_compute import _check_known
from tests.dask_processes import REPO, dask_processes, kill


@pytest.mark.slow
def test_a_killed_worker_costs_only_its_batches_and_the_run_finishes(tmp_path, rng):
    folder = tmp_path / "r"
    params = write_render_set(folder, rng, n_images=60)
    out = tmp_path / "stats.parquet"
    parts = tmp_path / "stats.parquet.partial"
    err_path = tmp_path / "stats.err"
    with dask_processes(tmp_path / "dask") as dask:
        first = dask.start_worker(nthreads=2)
        dask.wait_workers(1)
        with open(err_path, "w") as err_file:
            proc = subprocess.Popen(
                [sys.executable, "-m", "analysis", "imagestats", str(folder), "--out", str(out),
                 "--scheduler", dask.address, "--batch-size", "2", "--quiet",
                 "--no-worker-timeout", "1"],
                cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, start_new_session=True,
                stdout=subprocess.PIPE, stderr=err_file, text=True)
        try:
            deadline = time.monotonic() + 120
            while not list(parts.glob("part-*.parquet")):
                assert proc.poll() is None, err_path.read_text()
                assert time.monotonic() < deadline, "no batch in 120 s\n" + dask.logs()
                time.sleep(0.005)
            kill(first)
            n_at_kill = len(list(parts.glob("part-*.parquet")))
            assert n_at_kill < 30, "all batches were done before the kill: the test proves nothing"
            while "no Dask worker connected" not in err_path.read_text():
                assert proc.poll() is None, err_path.read_text()
                assert time.monotonic() < deadline + 60, "no message while no worker was left"
                time.sleep(0.1)
            dask.start_worker(nthreads=2)
            stdout = proc.communicate(timeout=180)[0]
        finally:
            kill(proc)
    err = err_path.read_text()
    assert proc.returncode == 0, err + dask.logs()
    assert "Traceback" not in err, err
    assert f"dask worker {dask.address}" in err
    assert "1 Dask worker(s) left (tcp://127.0.0.1:" in err and "worker(s) joined" in err
    assert "60 images in the manifest, 0 already done, 60 computed" in stdout
    frame = load_stats(out)
    assert frame["stimulus_id"].is_unique
    _check_known(frame, params)  # every image once, with its known statistics


def test_cluster_dry_run_prints_the_job_script(tmp_path, capsys):
    rc = main([str(tmp_path), "--out", str(tmp_path / "s.parquet"), "--cluster", "slurm",
               "--cores", "2", "--memory", "4GiB", "--walltime", "00:30:00", "--dry-run"])
    script = capsys.readouterr().out
    assert rc == 0
    assert "#SBATCH --cpus-per-task=2" in script and "#SBATCH -t 00:30:00" in script
    worker = next(line for line in script.splitlines() if "dask_worker" in line)
    assert worker.startswith(f"{sys.executable} -m distributed.cli.dask_worker tcp://")
    assert "--nworkers 2" in worker and "--nthreads 1" in worker  # a process per core
    assert not (tmp_path / "s.parquet").exists()
