"""A Dask cluster as users start it by hand (cellsight.sweep.engine): workers that cannot import
cellsight are named before any job is sent, and a sweep whose workers all die ends with one
clear error instead of waiting for ever."""

from __future__ import annotations

import threading
import time

import distributed
import pytest

from cellsight.errors import CellsightError
from cellsight.sweep.engine import check_workers, map_jobs


def test_workers_without_the_package_are_named():
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        check_workers(client, 10.0)  # cellsight itself imports everywhere
        with pytest.raises(CellsightError) as err:
            check_workers(client, 10.0, module="cellsight_not_installed_here")
    text = str(err.value)
    assert text.startswith("--scheduler: the scheduler, inproc://")
    assert "cannot import cellsight_not_installed_here" in text and "\n" not in text


@pytest.mark.slow
def test_a_sweep_whose_workers_all_die_ends_with_a_clear_error():
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        results = map_jobs(time.sleep, [0.1, 120.0, 120.0], scheduler=cluster.scheduler_address,
                           progress=False, connect_s=3.0)
        first = next(results)  # the short job: the cluster works
        threading.Timer(0.5, cluster.scale, args=(0,)).start()
        start = time.monotonic()
        with pytest.raises(CellsightError, match=r"every Dask worker is gone .* 1 of 3 jobs"):
            list(results)
    assert first == (0, None)
    assert time.monotonic() - start < 60
