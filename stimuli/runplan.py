"""The plan a render prints before it starts: images, hours on the workers it sees, and hours
with each added machine.

Cost model: an image costs ``CORE_S_PER_SAMPLE`` core-seconds per pixel sample (width x height x
spp) plus ``CORE_S_PER_IMAGE``; a machine's cores all work on it (one worker per machine, Dr.Jit
threads on every core). The constants come from the full image-statistics set: 58,564 images at
256 px with the design's spp per gloss level (39.1 on average) took about 44 h on one 2-core
machine, i.e. 5.4 core-seconds per image (of which about 0.3 s is per-image overhead: reading the
EXR back, hashing, logging). Machines differ: the progress bar's ETA, from this run's own pace,
replaces the estimate once images finish. :func:`measured_pace_text` then prints the plan again in
the pace of the machine the run is on (a GPU's, a cluster node's), fitted on its own images.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Sequence

__all__ = ["CORE_S_PER_IMAGE", "CORE_S_PER_SAMPLE", "core_seconds", "machines_seen",
           "measured_pace_text", "plan_text"]

#: Core-seconds per image independent of its size (scene update, EXR write, checksum).
CORE_S_PER_IMAGE = 0.3
#: Core-seconds per pixel sample: (5.4 - 0.3) s / (256 * 256 * 39.1).
CORE_S_PER_SAMPLE = (5.4 - CORE_S_PER_IMAGE) / (256 * 256 * 39.1)


def _duration(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def core_seconds(size_px: int, spp: Sequence[int]) -> float:
    """Estimated core-seconds to render images of ``size_px`` x ``size_px`` at these spp."""
    return sum(CORE_S_PER_IMAGE + CORE_S_PER_SAMPLE * size_px * size_px * int(s) for s in spp)


def _host_cores() -> tuple[str, int]:
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return socket.gethostname(), cores


def machines_seen(client) -> dict[str, int]:
    """``{host: cores}`` of the machines with a worker connected to ``client``'s scheduler
    (None client: this machine)."""
    if client is None:
        host, cores = _host_cores()
        return {host: cores}
    try:
        answers = client.run(_host_cores, wait=True)
    except (OSError, TimeoutError):  # a worker left while asked: count the others next time
        return {}
    return {host: cores for host, cores in answers.values()}


def plan_text(n_todo: int, n_done: int, size_px: int, spp: Sequence[int],
              machines: dict[str, int], *, seen: bool = True) -> str:
    """The plan as printed: images, hours on ``machines``, hours per added machine.

    ``seen``: the machines are the workers connected now (False: the batch jobs asked for).
    """
    total = core_seconds(size_px, spp)
    mean_spp = sum(spp) / len(spp) if len(spp) else 0.0
    lines = [(f"plan: {n_todo} images to render ({n_done} already done), {size_px} px, "
              f"{mean_spp:.1f} spp on average: about {total / 3600:.1f} core-hours "
              f"({total / max(n_todo, 1):.1f} core-s per image, the 2-core reference machine's "
              "pace; the progress bar's ETA is this run's own)")]
    if not machines:
        here = _host_cores()[1]
        lines.append(f"  no worker connected yet; on one {here}-core machine: "
                     f"{_duration(total / here)}")
        return "\n".join(lines)
    cores = sum(machines.values())
    per_machine = cores / len(machines)
    which = "workers seen" if seen else "jobs asked for, once they run"
    lines.append(f"  on the {which} ({len(machines)} machine(s), {cores} cores): "
                 f"{_duration(total / cores)}")
    added = ", ".join(f"+{k}: {_duration(total / (cores + k * per_machine))}"
                      for k in (1, 2, 4, 8))
    lines.append(f"  with added machines like these ({per_machine:g} cores each): {added}")
    return "\n".join(lines)


def measured_pace_text(timed: Sequence[tuple[float, int]], size_px: int, spp_left: Sequence[int],
                       n_workers: int) -> str:
    """The plan in the pace measured here: seconds per image = a + b x (pixel samples).

    Parameters
    ----------
    timed : sequence of (seconds, spp)
        Images rendered here (a worker's ``render_s``: render, EXR write, checksum), not the first
        group's (those include compiling each sample count's kernel).
    size_px : int
        Image width = height, px.
    spp_left : sequence of int
        The spp of every image still to render.
    n_workers : int
        Workers rendering side by side (one per machine).

    Returns
    -------
    str
        One line: the measured pace (s per image at the mean spp, ms per megasample) and the
        remaining wall time; a + b is fitted by least squares where the spp differ, else
        b = seconds / samples (a = 0).
    """
    import numpy as np

    s = np.array([t for t, _ in timed], dtype=float)
    samples = np.array([size_px * size_px * n for _, n in timed], dtype=float)
    if len(s) == 0:
        return "pace: no timed image yet"
    a, b = 0.0, float(s.sum() / samples.sum())
    if len(np.unique(samples)) > 1:
        b_fit, a_fit = np.polyfit(samples, s, 1)
        if b_fit > 0 and a_fit >= 0:
            a, b = float(a_fit), float(b_fit)
    left = a * len(spp_left) + b * size_px * size_px * float(np.sum(spp_left))
    return (f"pace measured here on {len(s)} images: {s.mean():.2f} s per image at "
            f"{np.mean([n for _, n in timed]):.1f} spp ({1e9 * b:.1f} ms per megasample + "
            f"{a:.2f} s per image); the {len(spp_left)} images left: about "
            f"{_duration(left / max(n_workers, 1))} on {n_workers} worker(s) at this pace")
