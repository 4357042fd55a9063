"""A computation in pieces on a worker, whose reader runs the pieces not yet started
(runtime.hybrid.pieces)."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from depthmocap.runtime.hybrid.pieces import PiecesInFlight


def _piece(k: int, ran: list, where: list):
    def run():
        ran.append(k)
        where.append(threading.current_thread().name)
        return np.array([k, 10 * k])

    return run


def test_the_reader_runs_what_the_worker_has_not_started():
    pool = ThreadPoolExecutor(1, thread_name_prefix="busy")
    gate = threading.Event()
    pool.submit(gate.wait)  # the worker is busy until the reader has taken the pieces
    ran, where = [], []
    work = PiecesInFlight(pool, [_piece(k, ran, where) for k in range(3)])
    assert not work.done()
    result = work.result()
    assert work.done()  # taken over: the worker has nothing of it left
    gate.set()
    pool.shutdown(wait=True)
    assert result.tolist() == [0, 0, 1, 10, 2, 20]  # in the pieces' order
    assert work.stolen == 3 and ran == [2, 1, 0]  # last first
    assert all(not name.startswith("busy") for name in where)


def test_a_free_worker_does_the_work():
    pool = ThreadPoolExecutor(1)
    ran, where = [], []
    work = PiecesInFlight(pool, [_piece(k, ran, where) for k in range(3)])
    pool.shutdown(wait=True)  # every piece done before the read
    assert work.done()
    assert work.result().tolist() == [0, 0, 1, 10, 2, 20]
    assert work.stolen == 0 and sorted(ran) == [0, 1, 2]


def test_errors_reach_the_reader():
    pool = ThreadPoolExecutor(1)

    def fails():
        raise RuntimeError("refit failed")

    work = PiecesInFlight(pool, [fails, lambda: np.zeros(2)])
    with pytest.raises(RuntimeError, match="refit failed"):
        work.result()
    pool.shutdown(wait=True)
