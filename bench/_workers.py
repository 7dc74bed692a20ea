"""The Dask worker set-ups the rendering benches compare, started side by side.

Shared by ``stimuli_dask_scaling.py`` and ``stimuli_throughput.py`` (run as scripts, so this
module is found beside them): one worker with one thread, one worker per core with one thread
each, and one worker per machine with every core as Dr.Jit threads (the default).
"""

from __future__ import annotations

import logging
from contextlib import contextmanager


def worker_configs(cores: int) -> dict:
    """``{name: (workers, Dr.Jit threads per worker)}``."""
    return {"1 worker x 1 thread": (1, 1), f"{cores} workers x 1 thread": (cores, 1),
            f"1 worker x {cores} threads": (1, cores)}


@contextmanager
def clients(configs: dict):
    """A Dask client per set-up (local process clusters, all up at once), closed on exit."""
    from dask.distributed import Client, LocalCluster

    clusters, out = {}, {}
    try:
        for name, (n, _) in configs.items():
            clusters[name] = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                          dashboard_address=":0", silence_logs=logging.ERROR)
            out[name] = Client(clusters[name])
        yield out
    finally:
        logging.getLogger("distributed").setLevel(logging.ERROR)  # no shutdown chatter
        for c in out.values():
            c.close()
        for c in clusters.values():
            c.close()
