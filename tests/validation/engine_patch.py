"""The engine side of the gallery's perturbation tests, written once: within ``engine_builds_with(f)``
every module of the engine and the policy that imported ``scene.batch.column_batch`` builds its
columns with ``f`` instead; the validation references (``warp_tensegrity.validation``) keep the true
builder. Used by test_perturbation.py, test_preload_check.py and test_striker_check.py."""

import sys
from contextlib import contextmanager

import warp_tensegrity.scene.batch as scene_batch

ORIGINAL = scene_batch.column_batch


@contextmanager
def engine_builds_with(column_batch):
    patched = [m for k, m in list(sys.modules.items())
               if k.startswith("warp_tensegrity.") and not k.startswith("warp_tensegrity.validation")
               and k != "warp_tensegrity.scene.batch" and getattr(m, "column_batch", None) is ORIGINAL]
    assert any(m.__name__ == "warp_tensegrity.engine" for m in patched)
    for m in patched:
        m.column_batch = column_batch
    try:
        yield
    finally:
        for m in patched:
            m.column_batch = ORIGINAL
