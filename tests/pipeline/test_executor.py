"""Executors: results in input order, a bounded window of items in flight, shared objects, errors raised."""

import time

import numpy as np
import pytest

from featmap.pipeline.executor import ProcessExecutor, SerialExecutor


def _slow_square(x):
    time.sleep(0.02 * ((7 * x) % 5))      # later items often finish first
    return x * x


def _sum_with(task):
    shared, k = task
    return float(shared[k].sum())


def _fail_on_three(x):
    if x == 3:
        raise ValueError("item three")
    return x


def _check_contract(executor, window):
    consumed = []

    def items():
        for k in range(12):
            consumed.append(k)
            yield k

    results = []
    for value in executor.imap(_slow_square, items()):
        results.append(value)
        assert len(consumed) - len(results) <= window          # never more than the window in flight
    assert results == [k * k for k in range(12)]
    big = np.arange(40_000.0).reshape(4, 10_000)
    shared = executor.share(big)
    assert list(executor.imap(_sum_with, ((shared, k) for k in range(4)))) == [float(r.sum()) for r in big]
    with pytest.raises(ValueError, match="item three"):
        list(executor.imap(_fail_on_three, range(6)))


def test_serial_and_process_executors():
    _check_contract(SerialExecutor(), 1)
    with ProcessExecutor(2, window=3) as executor:
        _check_contract(executor, 3)


def test_dask_executor_keeps_the_same_contract(dask_client):
    from featmap.pipeline.executor import DaskExecutor

    executor = DaskExecutor(dask_client, window=3)
    _check_contract(executor, 3)
    assert DaskExecutor(dask_client).window == 4         # two per worker thread by default
