"""`python -m analysis imagestats RENDER_DIR --out FILE` on real EXR/PNG files and manifests:
known statistics, bad input listed per image, a kill and a resume, 1 vs 2 Dask workers."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.imagestats import StatsConfig, compute_stats, load_stats, problems_path
from analysis.imagestats.__main__ import main
from stimuli import MANIFEST_COLUMNS, load_manifest, sha256_file
from tests.analysis.imagestats.renders import (
    EXTENT_CM,
    expected_stats,
    write_exr,
    write_render_set,
)

REPO = Path(__file__).resolve().parents[3]


def _check_known(frame: pd.DataFrame, params: dict) -> None:
    assert sorted(frame["stimulus_id"]) == sorted(params)
    for row in frame.itertuples(index=False):
        for name, value in expected_stats(*params[row.stimulus_id]).items():
            assert getattr(row, name) == pytest.approx(value, rel=1e-6), (row.stimulus_id, name)


def test_cli_computes_known_statistics_keyed_by_the_manifest(tmp_path, rng, capsys, scheduler):
    params = write_render_set(tmp_path / "r", rng, n_images=5)
    out = tmp_path / "stats.parquet"
    args = [str(tmp_path / "r"), "--out", str(out), "--scheduler", scheduler, "--batch-size", "2",
            "--quiet"]
    assert main(args) == 0
    frame = load_stats(out)
    _check_known(frame, params)
    manifest = load_manifest(tmp_path / "r").set_index("stimulus_id")
    keyed = frame.set_index("stimulus_id").loc[manifest.index]
    for col in MANIFEST_COLUMNS[1:]:
        a, b = keyed[col], manifest[col]
        assert ((a.astype(str) == b.astype(str)) | (a.isna() & b.isna())).all(), col
    assert sum(c.startswith("ps_") for c in frame.columns) == 710
    assert frame.attrs["imagestats"]["config"]["highlight_factor"] == 2.0
    assert not (tmp_path / "stats.parquet.partial").exists()
    # a second run finds everything done and changes nothing
    before = sha256_file(out)
    assert main(args) == 0
    assert "5 already done, 0 computed" in capsys.readouterr().out
    assert sha256_file(out) == before
    # other options on the same table are refused
    assert main(args + ["--no-ps"]) == 1
    assert "other options" in capsys.readouterr().err
    # new renders in the folder: only they are computed, merged into a new table
    params |= write_render_set(tmp_path / "r", rng, n_images=2,
                               cells=[("outdoor", 9, 9), ("outdoor", 10, 10)])
    assert main(args) == 0
    assert "5 already done, 2 computed" in capsys.readouterr().out
    _check_known(load_stats(out), params)


def _rewrite_manifest(folder: Path, sid: str, **changes) -> None:
    manifest = pd.read_csv(folder / "manifest.csv", dtype=str)
    for col, value in changes.items():
        manifest.loc[manifest["stimulus_id"] == sid, col] = value
    manifest.to_csv(folder / "manifest.csv", index=False)


def test_bad_input_is_listed_per_image_never_skipped(tmp_path, rng, capsys, scheduler):
    folder = tmp_path / "r"
    params = write_render_set(folder, rng, n_images=7)
    sids = sorted(params)
    nan_img = np.ones((144, 160), np.float32)
    nan_img[70, 80] = np.nan
    write_exr(folder / "exr" / f"{sids[0]}.exr", nan_img)
    _rewrite_manifest(folder, sids[0], exr_sha256=sha256_file(folder / "exr" / f"{sids[0]}.exr"))
    (folder / "exr" / f"{sids[1]}.exr").write_bytes(b"not an exr")
    _rewrite_manifest(folder, sids[1], exr_sha256=sha256_file(folder / "exr" / f"{sids[1]}.exr"))
    (folder / "exr" / f"{sids[2]}.exr").unlink()
    with open(folder / "exr" / f"{sids[3]}.exr", "ab") as fh:
        fh.write(b"\0")
    write_exr(folder / "exr" / "stray.exr", np.ones((144, 160), np.float32))
    (folder / "png" / f"{sids[4]}.png").unlink()
    expected = {
        sids[0]: "NaN or Inf", sids[1]: "not a readable OpenEXR", sids[2]: "is missing",
        sids[3]: "does not match its checksum", "exr/stray.exr": "not in its manifest",
        sids[4]: "is missing",
    }
    out = tmp_path / "stats.parquet"
    args = [str(folder), "--out", str(out), "--scheduler", scheduler, "--quiet", "--no-ps"]
    for attempt in range(2):  # the second run lists the same problems again
        assert main(args) == 1
        err = capsys.readouterr().err
        listed = pd.read_csv(problems_path(out))
        for item, message in expected.items():
            assert any(message in line for line in err.splitlines() if item in line), item
            assert listed["problem"][listed["item"] == item].str.contains(message).any(), item
        assert f"{len(listed)} problems" in err and len(listed) == len(expected)
    # the images that could be measured are in the table (sids[4] lacks only its PNG)
    _check_known(load_stats(out), {s: params[s] for s in sids[4:]})


def test_missing_manifest_is_a_clear_error(tmp_path, capsys):
    assert main([str(tmp_path), "--out", str(tmp_path / "s.parquet"), "--quiet"]) == 1
    assert "manifest" in capsys.readouterr().err


def test_a_killed_run_resumes_without_losing_finished_batches(tmp_path, rng, scheduler, design):
    folder = tmp_path / "r"
    params = write_render_set(folder, rng, n_images=40)
    out = tmp_path / "stats.parquet"
    parts = tmp_path / "stats.parquet.partial"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "analysis", "imagestats", str(folder), "--out", str(out),
         "--scheduler", scheduler, "--batch-size", "2", "--quiet"],
        cwd=REPO, env=env, start_new_session=True, stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while not list(parts.glob("part-*.parquet")):
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() < deadline, "no batch was written within 120 s"
        time.sleep(0.005)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not out.exists(), "the run finished before the kill; the test proves nothing"
    survived = pd.concat([pd.read_parquet(p) for p in parts.glob("part-*.parquet")])
    assert len(survived) >= 2 and len(survived) % 2 == 0
    run = compute_stats(folder, out, design=design, scheduler=scheduler, batch_size=8,
                        progress=False)
    assert run.ok and run.n_skipped == len(survived) and run.n_computed == 40 - len(survived)
    frame = load_stats(out)
    assert frame["stimulus_id"].is_unique
    _check_known(frame, params)
    assert not parts.exists()


def test_one_and_two_dask_workers_give_the_same_table(tmp_path, rng, design, scheduler):
    write_render_set(tmp_path / "r", rng, n_images=6)
    runs = [compute_stats(tmp_path / "r", tmp_path / "w1.parquet", design=design, workers=1,
                          batch_size=2, progress=False),
            compute_stats(tmp_path / "r", tmp_path / "w2.parquet", design=design,
                          scheduler=scheduler, batch_size=2, progress=False)]
    assert [r.workers for r in runs] == [1, 2]
    one, two = (load_stats(r.path).drop(columns="stats_s") for r in runs)
    pd.testing.assert_frame_equal(one, two, check_exact=True)


def test_a_table_from_other_files_is_refused(tmp_path, rng, capsys, scheduler):
    folder = tmp_path / "r"
    write_render_set(folder, rng, n_images=2)
    out = tmp_path / "stats.parquet"
    args = [str(folder), "--out", str(out), "--scheduler", scheduler, "--quiet", "--no-ps"]
    assert main(args) == 0
    sid = load_manifest(folder)["stimulus_id"].iloc[0]
    write_exr(folder / "exr" / f"{sid}.exr", np.full((144, 160), 2.0, np.float32))
    _rewrite_manifest(folder, sid, exr_sha256=sha256_file(folder / "exr" / f"{sid}.exr"))
    before = sha256_file(out)
    assert main(args) == 1
    assert "computed from other files" in capsys.readouterr().err
    other = tmp_path / "other"
    write_render_set(other, np.random.default_rng(5), n_images=1,
                     cells=[("outdoor", 3, 3)])
    assert main([str(other)] + args[1:]) == 1
    assert "not in this manifest" in capsys.readouterr().err
    assert sha256_file(out) == before  # the table is never touched by a refused run


def test_a_kill_between_table_and_part_removal_keeps_each_row_once(tmp_path, rng, design,
                                                                   scheduler):
    """Parts left beside a finished table (a kill inside consolidate) are merged, not doubled."""
    folder = tmp_path / "r"
    params = write_render_set(folder, rng, n_images=3)
    out = tmp_path / "stats.parquet"
    compute_stats(folder, out, design=design, scheduler=scheduler, progress=False,
                  config=StatsConfig(ps=False))
    parts = tmp_path / "stats.parquet.partial"
    parts.mkdir()
    (parts / "meta.json").write_text(json.dumps(load_stats(out).attrs["imagestats"],
                                                sort_keys=True))
    load_stats(out).iloc[:2].to_parquet(parts / "part-000000.parquet", index=False)
    run = compute_stats(folder, out, design=design, scheduler=scheduler, progress=False,
                        config=StatsConfig(ps=False))
    assert run.ok and run.n_skipped == 3 and run.n_computed == 0
    frame = load_stats(out)
    assert len(frame) == 3
    _check_known(frame, params)
    assert not parts.exists()


@pytest.mark.slow
def test_statistics_of_real_mitsuba_renders(tmp_path, design, scheduler):
    """The contract with the renderer: its manifest, EXR channel and image geometry."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    env.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
    render = subprocess.run(
        [sys.executable, "-m", "stimuli", "render", "--set", "preview", "--filter",
         "illumination=indoor", "--size", "192", "--spp", "4", "--workers", "0", "--out",
         str(tmp_path / "r"), "--no-progress"],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert render.returncode == 0, render.stderr[-2000:]
    run = compute_stats(tmp_path / "r", tmp_path / "s.parquet", design=design,
                        scheduler=scheduler, progress=False)
    assert run.ok, run.problems
    frame = load_stats(run.path)
    manifest = load_manifest(tmp_path / "r")
    assert sorted(frame["stimulus_id"]) == sorted(manifest["stimulus_id"]) and len(frame) == 4
    side = round(EXTENT_CM * 192 / float(manifest["image_width_cm"].iloc[0]))
    assert (frame["region_px"] == side).all() and (frame["texture_window_px"] == 128).all()
    stats = frame[["mean_luminance", "rms_contrast", "skewness", "kurtosis",
                   "highlight_coverage"]].to_numpy()
    assert np.isfinite(stats).all() and (frame["mean_luminance"] > 0).all()
    assert ((frame["highlight_coverage"] >= 0) & (frame["highlight_coverage"] < 0.5)).all()
    # glossier arrays of the same depth have more highlight pixels (preview: lowest and highest
    # rendered gloss at the lowest and highest rendered depth)
    by = frame.set_index(["gloss_level", "depth_level"])["highlight_coverage"]
    g_lo, g_hi = sorted(frame["gloss_level"].unique())
    for d in frame["depth_level"].unique():
        assert by[(g_hi, d)] > by[(g_lo, d)]


def test_a_truncated_part_is_named_moved_aside_and_measured_again(tmp_path, rng, design,
                                                                   scheduler, capsys):
    """A part cut short ("Parquet magic bytes not found") used to end the run with a traceback;
    it is named, moved to <out>.damaged/ and its images are measured again."""
    folder = tmp_path / "r"
    params = write_render_set(folder, rng, n_images=4)
    first = compute_stats(folder, tmp_path / "ref.parquet", design=design, scheduler=scheduler,
                          progress=False, config=StatsConfig(ps=False))
    table = load_stats(first.path)
    out = tmp_path / "stats.parquet"
    parts = tmp_path / "stats.parquet.partial"
    parts.mkdir()
    (parts / "meta.json").write_text(json.dumps(table.attrs["imagestats"], sort_keys=True))
    table.iloc[:2].to_parquet(parts / "part-000000.parquet", index=False)
    table.iloc[2:].to_parquet(parts / "part-000001.parquet", index=False)
    damaged = parts / "part-000001.parquet"
    damaged.write_bytes(damaged.read_bytes()[: damaged.stat().st_size // 2])
    args = [str(folder), "--out", str(out), "--scheduler", scheduler, "--quiet", "--no-ps"]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert f"warning: {damaged} does not read as Parquet" in err
    kept = list((tmp_path / "stats.parquet.damaged").glob("part-000001-*.parquet"))
    assert len(kept) == 1 and str(kept[0]) in err
    frame = load_stats(out)
    assert frame["stimulus_id"].is_unique
    _check_known(frame, params)
    assert not parts.exists()


@pytest.mark.slow
def test_ctrl_c_ends_the_run_cleanly_and_it_resumes(tmp_path, rng, scheduler, design):
    # Ctrl-C must come while batches are still running. On a loaded machine the remaining
    # batches of a small set can all finish between the first part file and the signal (the
    # test would then prove nothing): then the same is tried on a set four times as large.
    for attempt, n_images in enumerate((40, 160)):
        folder = tmp_path / f"r{attempt}"
        params = write_render_set(folder, rng, n_images=n_images)
        out = tmp_path / f"stats{attempt}.parquet"
        parts = tmp_path / f"stats{attempt}.parquet.partial"
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        proc = subprocess.Popen(
            [sys.executable, "-m", "analysis", "imagestats", str(folder), "--out", str(out),
             "--scheduler", scheduler, "--batch-size", "2", "--quiet"],
            cwd=REPO, env=env, start_new_session=True, stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 120
        while not list(parts.glob("part-*.parquet")):
            assert proc.poll() is None, proc.stderr.read()
            assert time.monotonic() < deadline, "no batch was written within 120 s"
            time.sleep(0.005)
        os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in the terminal does
        err = proc.communicate(timeout=60)[1]
        if not out.exists():
            break
    assert not out.exists(), "the run finished before Ctrl-C twice; the test proves nothing"
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert f"finished batch(es) are kept in {parts}; run the same command to resume" in err
    run = compute_stats(folder, out, design=design, scheduler=scheduler, batch_size=8,
                        progress=False)
    assert run.ok and run.n_skipped >= 2
    _check_known(load_stats(out), params)


@pytest.mark.slow
def test_ctrl_c_with_the_local_cluster_prints_no_worker_tracebacks(tmp_path, rng):
    """Ctrl-C in a terminal signals the whole process group, the local cluster's workers too:
    they used to die with tracebacks over the clean message; they ignore it, and the run stops
    them."""
    folder = tmp_path / "r"
    write_render_set(folder, rng, n_images=60)
    out = tmp_path / "stats.parquet"
    parts = tmp_path / "stats.parquet.partial"
    # On a quiet machine the 60 images can all be done before the signal lands (seen once in
    # `make test`): then the run is started again from scratch, as the resume test does.
    for _attempt in range(2):
        out.unlink(missing_ok=True)
        shutil.rmtree(parts, ignore_errors=True)
        proc = subprocess.Popen(
            [sys.executable, "-m", "analysis", "imagestats", str(folder), "--out", str(out),
             "--workers", "2", "--batch-size", "2", "--quiet", "--no-ps"],
            cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, start_new_session=True,
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 180
        while not list(parts.glob("part-*.parquet")):
            assert proc.poll() is None, proc.stderr.read()
            assert time.monotonic() < deadline, "no batch was written within 180 s"
            time.sleep(0.005)
        os.killpg(proc.pid, signal.SIGINT)
        err = proc.communicate(timeout=120)[1]
        if not out.exists():
            break
    assert not out.exists(), "the run finished before Ctrl-C twice; the test proves nothing"
    assert proc.returncode == 130, err
    assert "Traceback" not in err, err
    assert "run the same command to resume" in err
