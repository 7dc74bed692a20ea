"""Render a stimulus set into a folder: EXRs on Dask workers, then tone mapping, PNGs, manifest.

Folder layout (paths in the manifest are relative to it)::

    OUT/manifest.csv            one row per finished stimulus (MANIFEST_COLUMNS), fsynced per row
    OUT/renders.csv             one row per finished EXR (pass 1 record, fsynced per row)
    OUT/tonemaps.csv            one row per light field: its probe and its tone curve
                                (TONEMAP_COLUMNS), rewritten atomically after each run
    OUT/exr/<light_field>/<stimulus_id>.exr   float32 luminance (CIE Y), channel "Y"
    OUT/png/<light_field>/<stimulus_id>.png   8-bit grey, tone-mapped and gamma-corrected

Pass 1 renders EXRs. Stimuli are grouped by (light field, array) so a worker builds each scene once
and renders all gloss levels of the group by updating the Ward parameters in place, each at its
gloss level's samples per pixel (``RenderJob.spp_by_gloss_level``, from the design's displayed-error
target). A worker is one process per machine whose Dr.Jit threads use all its cores
(``RenderJob.threads``); more machines, not more processes, give more throughput. A worker with
several Dask threads (``dask worker``'s default: one per core) renders one group at a time, with
Dr.Jit's threads on the cores its process may use; its other threads wait. Workers may join and
leave during a run (:func:`stimuli.dask_cluster.finished`): one that dies costs only its groups in
flight, which other workers render again. Pass 2 waits
for every EXR of a light field (its tone-mapping condition), computes the condition's L_max, and
writes PNGs and manifest rows, and records the curve of each light field beside them
(``tonemaps.csv``: the seed's map fitted once per light field). Every file is written to a hidden
temporary name and renamed, so an interrupted run (Ctrl-C, kill, disk full) leaves no
half-written file under a real name; re-running the same command skips every EXR whose logged
checksum and settings verify and every manifest row whose files verify, and finishes the rest.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import zlib
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from labfiles import TEMPORARY_GLOB, append_csv_record, read_csv_records
from stimuli.dask_cluster import ClusterError
from stimuli.errors import StimuliError
from stimuli.geometry import draw_array
from stimuli.glosstable import ward_params_for_gloss
from stimuli.illumination import load_light_probe, probe_path, write_exr
from stimuli.manifest import check_one_calibration, sha256_file
from stimuli.pngpass import (
    LOG_TEXT,
    TONEMAP_COLUMNS,
    TonemapWriter,
    progress_bar,
    tonemap_light_fields,
)
from stimuli.probecheck import refuse_bad_light_fields
from stimuli.render import StimulusRenderer
from stimuli.renderjob import RenderJob
from stimuli.sets import refuse_mixed_sets

__all__ = ["RENDER_LOG_COLUMNS", "TONEMAP_COLUMNS", "RenderJob", "render_group", "render_set"]

RENDER_LOG_COLUMNS = ["stimulus_id", "exr_path", "exr_sha256", "spp", "width_px", "rho_d", "rho_s",
                      "alpha", "seed", "variant", "envmap_sha256", "rotation_deg", "render_s"]

# --- worker side ---------------------------------------------------------------------------------
_worker: dict = {}
#: One group at a time per process: the scene, the renderer and Dr.Jit's thread pool are shared
#: by the worker's threads.
_render_lock = threading.Lock()


def _usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))  # a batch job's share, not the whole node
    except AttributeError:
        return os.cpu_count() or 1


def render_group(job: RenderJob, rows: list[dict], out_dir: str) -> list[dict]:
    """Render one group of stimuli that share a light field and an array (runs on a worker).

    Builds the scene once and re-renders it per Ward material. Returns one render-log record per
    EXR written (:data:`RENDER_LOG_COLUMNS`). Safe to call from several threads of one process:
    they render one after another.
    """
    with _render_lock:
        return _render_group(job, rows, out_dir)


def _render_group(job: RenderJob, rows: list[dict], out_dir: str) -> list[dict]:
    from stimuli.mitsuba_env import setup_mitsuba, use_llvm_hint
    from studydesign import load_design

    use_llvm_hint(job.llvm_path)
    variant = setup_mitsuba(job.variant)
    threads = job.threads or _usable_cores()
    if _worker.get("threads") != threads:
        import drjit as dr

        dr.set_thread_count(threads)
        _worker["threads"] = threads
    key = (job.camera, job.size_px, job.spp)
    if _worker.get("key") != key:
        _worker["renderer"] = StimulusRenderer(job.camera, size_px=job.size_px, spp=job.spp)
        _worker["key"] = key
    renderer = _worker["renderer"]
    design = _worker.get("design") if _worker.get("design_path") == job.design_path else None
    if design is None:
        design = load_design(job.design_path or None)
        _worker["design"], _worker["design_path"] = design, job.design_path
    first = rows[0]
    scale = float(first.get("envmap_scale", float("nan")))
    scale = None if np.isnan(scale) else scale  # NaN: mean luminance 1 (designs without scales)
    probe_key = (first["envmap"], first["rotation_deg"], scale)
    if _worker.get("probe_key") != probe_key:
        _worker["probe"] = load_light_probe(first["envmap"], rotation_deg=first["rotation_deg"],
                                            scale=scale)
        _worker["probe_key"] = probe_key
    probe = _worker["probe"]
    geometry = draw_array(design, first["true_depth_cm"], int(first["seed"]))
    renderer.load(geometry, probe)
    records = []
    for row in rows:
        t0 = time.perf_counter()
        spp = renderer.spp_for(job.spp_for(row["gloss_level"], row.get("light_field", "")))
        img = renderer.render(row["rho_d"], row["rho_s"], row["alpha"], spp=spp,
                              seed=zlib.crc32(row["stimulus_id"].encode()))
        path = Path(out_dir) / row["exr_path"]
        path.parent.mkdir(parents=True, exist_ok=True)
        write_exr(path, img)
        records.append({
            "stimulus_id": row["stimulus_id"], "exr_path": row["exr_path"],
            "exr_sha256": sha256_file(path), "spp": spp, "width_px": job.size_px,
            "rho_d": row["rho_d"], "rho_s": row["rho_s"], "alpha": row["alpha"],
            "seed": int(row["seed"]), "variant": variant, "envmap_sha256": probe.sha256,
            "rotation_deg": row["rotation_deg"], "render_s": round(time.perf_counter() - t0, 4),
        })
    return records


# --- driver side ---------------------------------------------------------------------------------
def _append_csv(path: Path, columns: list[str], row: dict) -> None:
    append_csv_record(path, columns, [row.get(c, "") for c in columns])


def _remove_stale_temporaries(out: Path, subs=("exr", "png")) -> int:
    """Remove the temporary files a killed writer left under ``out/<sub>``; returns how many."""
    n = 0
    for sub in subs:
        for f in (out / sub).rglob(TEMPORARY_GLOB):
            f.unlink()
            n += 1
    return n


def _plan_rows(table: pd.DataFrame, gloss_table: pd.DataFrame, job: RenderJob) -> pd.DataFrame:
    t = table.copy()
    t["spp"] = [job.spp_for(g, lf) for g, lf in zip(t["gloss_level"], t["light_field"])]
    rho_d, rho_s, alpha = ward_params_for_gloss(gloss_table, t["true_gloss_pct"].to_numpy())
    t["rho_d"], t["rho_s"], t["alpha"] = rho_d, rho_s, alpha
    t["exr_path"] = [f"exr/{lf}/{sid}.exr" for lf, sid in zip(t["light_field"], t["stimulus_id"])]
    t["png_path"] = [f"png/{lf}/{sid}.png" for lf, sid in zip(t["light_field"], t["stimulus_id"])]
    return t


def _done_exrs(out: Path, plan: pd.DataFrame, job: RenderJob) -> set[str]:
    """Stimuli whose EXR is logged with these settings and still matches its checksum."""
    log = out / "renders.csv"
    if not log.is_file():
        return set()
    try:
        done = read_csv_records(log, dtype=LOG_TEXT)
    except (pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        raise StimuliError(f"render log {log} is unreadable ({exc}); move it away and re-run "
                           "(finished EXRs will be rendered again)") from exc
    done = done.drop_duplicates("stimulus_id", keep="last").set_index("stimulus_id")
    probe_sha = {env: sha256_file(probe_path(env)) for env in plan["envmap"].unique()}
    ok = set()
    for row in plan.itertuples(index=False):
        if row.stimulus_id not in done.index:
            continue
        rec = done.loc[row.stimulus_id]
        if str(rec["envmap_sha256"]) != probe_sha[row.envmap]:
            # rendering it again would replace a recorded EXR (a design whose light field now
            # points at another file, e.g. the captures that replaced the studio probes)
            raise StimuliError(
                f"{log} records {row.stimulus_id} rendered under another light probe (checksum "
                f"{str(rec['envmap_sha256'])[:12]}..., not {row.envmap}'s "
                f"{probe_sha[row.envmap][:12]}...); recorded data are never overwritten: render "
                "into a new --out folder")
        same = (int(rec["spp"]) == int(row.spp) and int(rec["width_px"]) == job.size_px
                and np.isclose(rec["rho_d"], row.rho_d) and np.isclose(rec["rho_s"], row.rho_s)
                and np.isclose(rec["alpha"], row.alpha) and int(rec["seed"]) == int(row.seed))
        f = out / row.exr_path
        if same and f.is_file() and sha256_file(f) == rec["exr_sha256"]:
            ok.add(row.stimulus_id)
    return ok


class _Progress:
    """Pass 1's bookkeeping: each record logged, the pace measured on this machine's images
    (printed once, :func:`stimuli.runplan.measured_pace_text`), and each light field handed to
    ``on_light_field_done`` the moment its last EXR is logged."""

    def __init__(self, todo: pd.DataFrame, job: RenderJob, log: Path, bar, on_done, n_workers,
                 show_pace: bool):
        self.left = todo.groupby("light_field", sort=False).size().to_dict()
        self.light_field = dict(zip(todo["stimulus_id"], todo["light_field"], strict=True))
        self.spp_left = dict(zip(todo["stimulus_id"], todo["spp"], strict=True))
        self.job, self.log, self.bar, self.on_done = job, log, bar, on_done
        self.n_workers, self.show_pace = n_workers, show_pace
        self.groups_seen, self.n_rendered, self.timed = 0, 0, []

    def group(self, records: list[dict]) -> None:
        from stimuli.runplan import measured_pace_text

        self.groups_seen += 1
        if self.groups_seen > 1:  # the first group compiles the kernels of its sample counts
            self.timed += [(float(r["render_s"]), int(r["spp"])) for r in records]
        for rec in records:
            _append_csv(self.log, RENDER_LOG_COLUMNS, rec)
            self.n_rendered += 1
            self.bar.update(1)
            self.spp_left.pop(rec["stimulus_id"], None)
            lf = self.light_field.get(rec["stimulus_id"])
            if lf is not None:
                self.left[lf] -= 1
                if self.left[lf] == 0 and self.on_done is not None:
                    self.on_done(lf)
        if self.show_pace and self.groups_seen == 2 and self.spp_left:
            self.show_pace = False
            self.bar.write(measured_pace_text(self.timed, self.job.size_px,
                                              list(self.spp_left.values()), self.n_workers),
                           file=sys.stderr)


def _render_pass(out: Path, plan: pd.DataFrame, job: RenderJob, client, progress: bool,
                 workers: dict, on_light_field_done=None) -> tuple[int, int]:
    """Pass 1: render every EXR of ``plan`` not already logged in ``renders.csv`` with these
    settings (and matching its checksum); log each as it is written. Returns (rendered, skipped).
    ``workers``: :func:`stimuli.dask_cluster.finished`'s options (what to start, no_worker_s).
    ``on_light_field_done(name)``: called as each light field's last EXR is logged.
    """
    from stimuli.runplan import machines_seen, plan_text

    done = _done_exrs(out, plan, job)
    todo = plan[~plan["stimulus_id"].isin(done)]
    groups = [g.to_dict("records") for _, g in todo.groupby(["light_field", "seed"], sort=False)]
    log = out / "renders.csv"
    machines = {}
    if len(todo) and workers.get("plan", True):
        machines = machines_seen(client)
        seen = bool(machines) or not workers.get("expected")
        print(plan_text(len(todo), len(done), job.size_px, list(todo["spp"]),
                        machines if seen else workers["expected"], seen=seen),
              file=sys.stderr, flush=True)
    bar = progress_bar(len(todo), "render EXR", progress)
    track = _Progress(todo, job, log, bar, on_light_field_done, max(len(machines), 1),
                      show_pace=workers.get("plan", True))
    try:
        if client is None:
            for rows in groups:
                track.group(render_group(job, rows, str(out)))
        else:
            from stimuli.dask_cluster import finished, per_worker

            def submit(rows):
                return client.submit(render_group, job, rows, str(out), pure=False)

            for records in finished(client, submit, groups,
                                    what_to_start=workers.get("what_to_start", ""),
                                    no_worker_s=workers.get("no_worker_s", 120.0),
                                    say=lambda m: bar.write(m, file=sys.stderr),
                                    in_flight=per_worker):
                track.group(records)
    finally:
        bar.close()
    if client is not None:
        # a worker killed mid-write left its temporary EXR; the PNGs are this process's own,
        # written on the tone-map thread while rendering goes on (never removed here)
        _remove_stale_temporaries(out, subs=("exr",))
    return track.n_rendered, len(done)


def _manifest_of_finished(out: Path, plan: pd.DataFrame, job: RenderJob, calibration,
                          tonemap_spec, calibration_sha256: str) -> str:
    """After pass 1 stopped early: tone map every light field whose EXRs are all rendered (its
    curve is then final) into the manifest, and say what is kept and how to finish."""
    done = _done_exrs(out, plan, job)
    complete = [lf for lf, group in plan.groupby("light_field", sort=False)
                if group["stimulus_id"].isin(done).all()]
    n_listed = 0
    if complete:
        n_png, n_skipped, _ = tonemap_light_fields(out, plan[plan["light_field"].isin(complete)], job,
                                            calibration, tonemap_spec, progress=False,
                                            calibration_sha256=calibration_sha256)
        n_listed = n_png + n_skipped
    rest = len(plan["light_field"].unique()) - len(complete)
    listed = (f"{n_listed} images of the {len(complete)} light field(s) whose renders are all "
              f"done are tone-mapped and listed in {out / 'manifest.csv'}" if complete else
              "no light field has all its EXRs yet, so none is tone-mapped")
    return (f"kept: {len(done)} of {len(plan)} EXRs rendered and logged in {out / 'renders.csv'}; "
            f"{listed}" + (f" (the other {rest} light field(s) are tone-mapped once all their "
                           "EXRs are rendered)" if complete and rest else "")
            + "; re-run the same command to finish: it resumes, finished EXRs are not rendered "
            "again")


def render_set(
    table: pd.DataFrame,
    out_dir: str | os.PathLike,
    *,
    job: RenderJob,
    gloss_table: pd.DataFrame,
    calibration,
    tonemap_spec,
    client=None,
    progress: bool = True,
    gloss_table_name: str = "",
    workers: dict | None = None,
    calibration_sha256: str = "",
) -> dict:
    """Render ``table`` (rows of a stimulus set) into ``out_dir`` (see the module docstring).

    Parameters
    ----------
    table : DataFrame
        Rows of :func:`stimuli.stimulus_set` (possibly filtered).
    out_dir : path-like
        Output folder (created).
    job : RenderJob
        Camera, size, spp, variant.
    gloss_table : DataFrame
        Validated gloss table (gloss % -> Ward parameters).
    calibration : calibration.Calibration
        Inverse gamma for the PNGs; its id goes into the manifest.
    calibration_sha256 : str
        SHA-256 of the calibration's file, recorded in the manifest (the command line passes
        it; empty for the built-in default curve, and then not checked).
    tonemap_spec : studydesign.ToneMapSpec
        The design's tone-map numbers.
    client : dask.distributed.Client, optional
        Where to run pass 1; None renders in this process.
    progress : bool
        Show a progress bar with ETA on stderr.
    gloss_table_name : str
        Recorded in the run summary.
    workers : dict, optional
        With a client: ``what_to_start`` (advice printed while no worker is connected),
        ``no_worker_s`` (after how many seconds), ``plan`` (print the plan first; default True),
        ``expected`` (``{name: cores}`` of batch jobs asked for, planned on while none runs).

    Returns
    -------
    dict
        Counts (rendered, skipped, pngs written, skipped), wall time, images per hour.

    Raises
    ------
    stimuli.dask_cluster.ClusterError
        If the Dask scheduler was lost (``SchedulerLost``) or a task killed its workers too often;
        the light fields whose EXRs are all rendered are tone-mapped into the manifest first, and
        the message says what is kept and that re-running the same command resumes.
    """
    out = Path(out_dir)
    check_one_calibration(out / "manifest.csv", calibration, calibration_sha256)
    refuse_mixed_sets(out, table)
    for sub in ("exr", "png"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    stale = _remove_stale_temporaries(out)
    plan = _plan_rows(table, gloss_table, job)
    refuse_bad_light_fields(plan, say=lambda m: print(m, file=sys.stderr))  # before any worker
    t0 = time.perf_counter()
    tonemap = {"calibration": calibration, "tonemap_spec": tonemap_spec,
               "calibration_sha256": calibration_sha256}
    writer = TonemapWriter(out, plan, job, tonemap)
    try:
        try:
            n_rendered, n_done = _render_pass(out, plan, job, client, progress, workers or {},
                                              on_light_field_done=writer.submit)
        finally:
            t_render = time.perf_counter() - t0
            t_end = time.monotonic()
            writer.close()  # the light fields in flight are finished before anything else
    except ClusterError as exc:  # the scheduler lost, a task that kills every worker
        kept = _manifest_of_finished(out, plan, job, calibration, tonemap_spec,
                                    calibration_sha256)
        raise type(exc)(f"{exc}\n{kept}") from None
    n_png, n_png_skipped = writer.counts()
    rest = plan[~plan["light_field"].isin(writer.started)]
    manifest_path = out / "manifest.csv"
    if len(rest):
        n, skipped, manifest_path = tonemap_light_fields(out, rest, job, calibration, tonemap_spec,
                                                  progress, calibration_sha256)
        n_png, n_png_skipped = n_png + n, n_png_skipped + skipped
    wall = time.perf_counter() - t0
    return {
        "n_stimuli": len(plan), "rendered": n_rendered, "render_skipped": n_done,
        "png_written": n_png, "png_skipped": n_png_skipped, "stale_temporaries_removed": stale,
        "render_s": round(t_render, 2), "wall_s": round(wall, 2),
        "images_per_hour": round(3600 * n_rendered / t_render, 1) if n_rendered else None,
        "gloss_table": gloss_table_name, "job": {k: v for k, v in asdict(job).items()
                                                 if k != "camera"},
        "camera": asdict(job.camera), "manifest": str(manifest_path),
        "tonemapped_while_rendering": [lf for lf, t in writer.started.items() if t < t_end],
    }
