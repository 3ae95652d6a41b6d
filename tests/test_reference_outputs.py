"""Refactors keep results bit-identical: ci_small, paper_2017 (truncated in time) and the holdout
scenes re-run in fp64 on the CPU and compared with np.array_equal against the file committed before
the layout change (benchmarks/reference_outputs.py writes it).

It runs in a fresh interpreter with NumPy's BLAS at its default thread count: tests/conftest.py caps
BLAS at one thread per xdist worker, and one stored output (base_mode_ratio, from an eigensolve)
differs at round-off between one thread and the default (two on the 2-core CI machine)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHECK = """
import numpy as np
from benchmarks.reference_outputs import REFERENCE_FILE, compare, compute
new = compute()
assert len(new) > 100 and any(np.asarray(v).size > 1000 for v in new.values())  # real histories
bad = compare(new, REFERENCE_FILE)
assert not bad, "outputs changed:\\n" + "\\n".join(bad[:20])
"""


def test_outputs_bit_identical_to_committed_reference(device):
    if device != "cpu":
        pytest.skip("the reference file holds CPU fp64 outputs")
    env = dict(os.environ)
    for var in filter(None, env.pop("WT_TEST_BLAS_CAPPED", "").split(",")):
        env.pop(var, None)
    r = subprocess.run([sys.executable, "-c", CHECK], cwd=ROOT, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
