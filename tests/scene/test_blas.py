"""The column build runs on one BLAS thread (scene/blas.py, issue 33), and gives the limit back: multi-threaded
OpenBLAS made the host's small solves up to 30x slower on a shared host."""

import numpy as np
import pytest

threadpoolctl = pytest.importorskip("threadpoolctl")

from warp_tensegrity import ColumnConfig  # noqa: E402
from warp_tensegrity.scene import blas as BM  # noqa: E402
from warp_tensegrity.scene import batch as SB  # noqa: E402


def _blas_threads() -> set:
    return {i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"}


def test_scene_solves_run_on_one_blas_thread(monkeypatch):
    seen = []
    svd, eigh = np.linalg.svd, np.linalg.eigh
    monkeypatch.setattr(np.linalg, "svd", lambda *a, **k: (seen.append(_blas_threads()), svd(*a, **k))[1])
    monkeypatch.setattr(np.linalg, "eigh", lambda *a, **k: (seen.append(_blas_threads()), eigh(*a, **k))[1])
    SB._constraint_range.cache_clear()
    cfg = ColumnConfig(n_prisms=3)
    with threadpoolctl.threadpool_limits(2, "blas"):  # what a 2-core host gives by default
        SB.column_batch(cfg, {"prestrain": np.array([0.001, 0.002]), "base_rigidity": np.array([0.0, 1.0])})
        BM.single_blas_thread(lambda: np.linalg.eigh(np.eye(3)))()  # what a GPU run's base-mode thread takes
        assert _blas_threads() == {2}  # given back
    assert seen and all(s == {1} for s in seen), seen
