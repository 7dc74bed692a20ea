"""A Dask cluster shared by the image-statistics tests (starting one costs seconds)."""

from __future__ import annotations

import logging

import pytest


@pytest.fixture(scope="module")
def scheduler() -> str:
    """Address of a local 2-worker Dask cluster (one thread per worker), closed after the module."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster:
        yield cluster.scheduler_address
