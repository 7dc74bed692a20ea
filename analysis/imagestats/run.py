"""Compute the statistics of every image of a render folder on Dask, resumably.

`compute_stats` reads the folder's manifest, checks it against the files, skips images already in
the output, sends the rest in batches to Dask (a ``LocalCluster`` by default, an existing
cluster's scheduler, or worker jobs on a batch system: `stimuli.dask_cluster`) and writes each
finished batch at once (see `analysis.imagestats.store`). Workers may join and leave during a run:
one that dies costs only its batches in flight, which other workers (or the next to join)
measure again; while none is connected the run says what to start and waits.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

import pandas as pd

from analysis.imagestats.config import StatsConfig
from analysis.imagestats.images import ImageStatsError
from analysis.imagestats.measure import measure_batch
from analysis.imagestats.store import (
    DamagedPartWarning,
    consolidate,
    discard_parts,
    has_parts,
    read_done,
    start,
    write_part,
)
from labfiles import atomic_open
from stimuli import MANIFEST_COLUMNS, ManifestError, load_manifest
from stimuli.dask_cluster import NO_WORKER_S, ClusterError, JobSpec, finished, open_client
from studydesign import StudyDesign

__all__ = ["StatsRun", "compute_stats", "dask_client", "problems_path"]


@dataclass(frozen=True)
class StatsRun:
    """What a `compute_stats` call did.

    Attributes
    ----------
    path : Path
        The statistics table (absent when no image could be measured).
    n_images : int
        Images in the manifest.
    n_skipped : int
        Images already in the table before this run (not recomputed).
    n_computed : int
        Images measured by this run.
    problems : tuple of (str, str)
        ``(stimulus_id or file, message)`` for every image that could not be measured and every
        file the manifest does not list; also written to `problems_path`.
    seconds : float
        Wall time of the run.
    workers : int
        Dask workers used (0 when nothing was left to compute).
    notes : tuple of str
        What was repaired on the way (a damaged part moved aside and measured again).
    """

    path: Path
    n_images: int
    n_skipped: int
    n_computed: int
    problems: tuple
    seconds: float
    workers: int
    notes: tuple = ()

    @property
    def ok(self) -> bool:
        return not self.problems


def problems_path(out: Path) -> Path:
    """Where a run lists the images it could not measure: ``<out>.problems.csv``."""
    return out.with_name(out.name + ".problems.csv")


@contextlib.contextmanager
def dask_client(*, workers: int = 2, scheduler: str | None = None, spec: JobSpec | None = None,
                advice: list | None = None):
    """A Dask client: on an existing scheduler, on worker jobs of a batch system (``spec``), or
    on a new ``LocalCluster``; closed on exit. ``advice``, if given, receives what to start
    while no worker is connected.

    The local cluster runs ``workers`` processes of one thread each (PyTorch and NumPy hold the
    GIL for parts of the work, so processes scale where threads would not).
    """
    if not scheduler and spec is None and workers < 1:
        raise ImageStatsError(f"--workers {workers}: use at least 1")

    def local():
        from distributed import LocalCluster

        with _workers_ignore_ctrl_c():
            # Worker logs at CRITICAL only: a task's error reaches this process through its
            # future; what the workers log at ERROR is their shutdown racing the scheduler's
            # (heartbeat tracebacks after Ctrl-C or a busy machine's slow close).
            return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                dashboard_address=None, silence_logs=logging.CRITICAL)

    try:
        with open_client(scheduler=scheduler, spec=spec, local=local) as (client, what):
            if advice is not None:
                advice.append(what)
            yield client
    except ClusterError as exc:  # no scheduler there, a lost task: the CLI's one-line error
        raise ImageStatsError(str(exc)) from exc


@contextlib.contextmanager
def _workers_ignore_ctrl_c():
    """Start worker processes with SIGINT ignored (they inherit it through ``exec``).

    Ctrl-C in a terminal signals the whole process group: the workers, hit too, died with
    tracebacks of their own over the run's clean message. Only this process must see it; it
    then closes the cluster, which ends the workers.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _folder_problems(manifest: pd.DataFrame, root: Path) -> list[tuple[str, str]]:
    """Files the manifest and the folder disagree on (missing EXRs are found when read)."""
    problems = []
    listed = {os.path.normpath(root / str(p)) for p in manifest["exr_path"]}
    listed |= {os.path.normpath(root / str(p)) for p in manifest["png_path"]}
    for path in sorted(root.rglob("*.exr")):
        if not any(part.startswith(".") for part in path.relative_to(root).parts) and \
                os.path.normpath(path) not in listed:
            message = (f"{path} is in the render folder but not in its manifest; re-render "
                       "the set or move the file out")
            problems.append((str(path.relative_to(root)), message))
    for row in manifest.itertuples(index=False):
        png = root / str(row.png_path)
        if not png.is_file():
            message = f"{png} (listed in the manifest) is missing; re-render it"
            problems.append((row.stimulus_id, message))
    return problems


def _check_done(done: pd.DataFrame, manifest: pd.DataFrame, out: Path) -> None:
    if not len(done):
        return
    known = manifest.set_index("stimulus_id")["exr_sha256"]
    stray = sorted(set(done["stimulus_id"]) - set(known.index))
    if stray:
        raise ImageStatsError(
            f"{out} holds statistics of {len(stray)} images not in this manifest ({stray[:3]}); "
            "it belongs to another render folder: write to a new --out"
        )
    changed = done["exr_sha256"].astype(str).to_numpy() != \
        known.loc[done["stimulus_id"]].astype(str).to_numpy()
    if changed.any():
        ids = done["stimulus_id"][changed].tolist()
        raise ImageStatsError(
            f"{out} holds statistics of {len(ids)} images computed from other files than the "
            f"manifest now lists ({ids[:3]}; the EXR checksums differ): write to a new --out"
        )


def compute_stats(render_dir: str | Path, out: str | Path, *, design: StudyDesign,
                  config: StatsConfig | None = None, workers: int = 2,
                  scheduler: str | None = None, batch_size: int = 64,
                  progress: bool = True, cluster: JobSpec | None = None,
                  no_worker_s: float = NO_WORKER_S) -> StatsRun:
    """Statistics of every image a render folder's manifest lists, into one Parquet table.

    Parameters
    ----------
    render_dir : path-like
        Folder holding ``manifest.csv`` and the files it lists (``python -m stimuli render``).
    out : path-like
        The Parquet table. If it exists (or an interrupted run left ``<out>.partial``), images
        already in it are skipped; it must have been made with the same options.
    design : StudyDesign
        Gives the array square (``array.extent_cm``) the statistics are computed on.
    config : StatsConfig, optional
        Highlight threshold and Portilla-Simoncelli options.
    workers : int
        Worker processes of the local Dask cluster (ignored with ``scheduler``).
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:8786``); its workers must see
        ``render_dir`` and ``out`` at the same paths.
    cluster : stimuli.dask_cluster.JobSpec, optional
        Run the workers as batch jobs (``--cluster slurm|pbs|sge``) instead.
    no_worker_s : float
        Seconds without any worker before the run says what to start (it keeps waiting).
    batch_size : int
        Images per Dask task and per part file (a kill loses at most the batches in flight).
    progress : bool
        Show a progress bar (tqdm) on stderr.

    Returns
    -------
    StatsRun
        Counts, timing, and every problem per image (also in `problems_path`).

    Raises
    ------
    ImageStatsError
        If the manifest is missing or malformed, or ``out`` was made with other options or from
        other files.
    """

    t0 = time.perf_counter()
    config = StatsConfig() if config is None else config
    root = Path(render_dir).resolve()
    out = Path(out).resolve()
    if batch_size < 1:
        raise ImageStatsError(f"--batch-size {batch_size}: use at least 1")
    try:
        manifest = load_manifest(root)
    except ManifestError as exc:
        raise ImageStatsError(str(exc)) from exc
    meta = {"config": asdict(config), "extent_cm": float(design.array.extent_cm),
            "image": "exr_luminance", "region": "array_square"}
    done, notes = _start(out, meta, manifest)
    problems = _folder_problems(manifest, root)
    batches = _todo_batches(manifest, done, batch_size)
    n_computed, n_workers = 0, 0
    if batches:
        n_computed, n_workers = _measure(batches, out, problems, root=root, design=design,
                                         config=config, progress=progress,
                                         client_options={"workers": workers,
                                                         "scheduler": scheduler,
                                                         "spec": cluster},
                                         no_worker_s=no_worker_s)
    stats_columns = list(MANIFEST_COLUMNS)
    if n_computed or (len(done) and has_parts(out)):
        consolidate(out, meta, stats_columns)
    else:  # nothing new: the table (if any) stays as it is
        discard_parts(out)
    _write_problems(problems_path(out), problems)
    return StatsRun(path=out, n_images=len(manifest), n_skipped=len(done),
                    n_computed=n_computed, problems=tuple(problems),
                    seconds=time.perf_counter() - t0, workers=n_workers, notes=notes)


def _start(out: Path, meta: dict, manifest: pd.DataFrame) -> tuple[pd.DataFrame, tuple[str, ...]]:
    """Start (or resume) the table ``out`` made with ``meta``, and read the images already in
    it, refusing a table of other files than ``manifest`` lists.

    Returns
    -------
    done : DataFrame
        The statistics already in ``out`` (and its parts).
    notes : tuple of str
        What was said of damaged parts (their images are measured again).
    """
    start(out, meta)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DamagedPartWarning)
        done = read_done(out)
    notes = tuple(str(w.message) for w in caught if issubclass(w.category, DamagedPartWarning))
    _check_done(done, manifest, out)
    return done, notes


def _todo_batches(manifest: pd.DataFrame, done: pd.DataFrame, batch_size: int) -> list[list[dict]]:
    """The manifest rows not yet in ``done``, as plain records (None for missing values) in
    batches of ``batch_size``."""
    todo = manifest[~manifest["stimulus_id"].isin(set(done["stimulus_id"]))]
    records = [
        {k: (None if pd.isna(v) else v) for k, v in row.items()}
        for row in todo[list(MANIFEST_COLUMNS)].to_dict(orient="records")
    ]
    return [records[i:i + batch_size] for i in range(0, len(records), batch_size)]


def _measure(batches: list, out: Path, problems: list, *, root: Path, design: StudyDesign,
             config: StatsConfig, progress: bool, client_options: dict,
             no_worker_s: float) -> tuple[int, int]:
    """Measure ``batches`` on Dask, writing each finished batch as a part and appending its
    problems to ``problems``. Returns (images measured, most workers seen at once)."""
    from tqdm import tqdm

    n_computed = 0
    advice: list[str] = []
    with dask_client(**client_options, advice=advice) as client, \
            tqdm(total=sum(len(b) for b in batches), unit="img", desc="image statistics",
                 disable=not progress) as bar:
        n_workers = len(client.nthreads())

        def submit(batch):
            return client.submit(measure_batch, batch, str(root), float(design.array.extent_cm),
                                 config.to_json(), pure=False)

        for batch_records, batch_problems in finished(
                client, submit, batches, what_to_start=advice[0], no_worker_s=no_worker_s,
                say=lambda m: bar.write(m, file=sys.stderr)):
            if batch_records:
                write_part(out, batch_records)
            n_computed += len(batch_records)
            problems += batch_problems
            bar.update(len(batch_records) + len(batch_problems))
            n_workers = max(n_workers, len(client.nthreads()))
    return n_computed, n_workers


def _write_problems(path: Path, problems: list[tuple[str, str]]) -> None:
    if not problems:
        path.unlink(missing_ok=True)
        return
    with atomic_open(path, "w", newline="", encoding="utf-8") as fh:
        pd.DataFrame(problems, columns=["item", "problem"]).to_csv(fh, index=False)
