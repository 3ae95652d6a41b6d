"""Refactors keep results: ci_small, paper_2017 (truncated in time) and the holdout scenes re-run in
fp64 on the CPU and compared with the committed file (benchmarks/reference_outputs.py writes it).

The scene build goes through OpenBLAS, whose kernels depend on the CPU (SkylakeX kernels where
there is AVX-512, Haswell's elsewhere, ...), and the outputs differ in the last bits between them.
So the check runs in a fresh interpreter with OpenBLAS pinned to the kernels and thread count the
file records (``pinned_blas_env``; conftest caps BLAS at one thread per xdist worker, undone here):
where the pin takes, every array must be bit-identical; where it cannot (another OpenBLAS version,
another BLAS, a CPU without the recorded kernels), every array must stay within its round-off
tolerance (``TOLERANCES``, each with its reason). The two other tests show that those tolerances
pass another kernel set and catch a real change far below any physical one."""

import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from benchmarks.reference_outputs import REFERENCE_FILE, compare_report, pinned_blas_env, recorded_blas

ROOT = Path(__file__).resolve().parents[1]
CHECK = """
import json
import numpy as np
from benchmarks.reference_outputs import REFERENCE_FILE, blas_signature, compare_report, compute
new = compute()
assert len(new) > 100 and any(np.asarray(v).size > 1000 for v in new.values())  # real histories
bad, same, within = compare_report(new, REFERENCE_FILE)
print(json.dumps({"bad": bad, "same": len(same), "within": sorted(within), "blas": blas_signature()}))
"""


def _check(env: dict) -> dict:
    for var in filter(None, env.pop("WT_TEST_BLAS_CAPPED", "").split(",")):
        env.pop(var, None)
    r = subprocess.run([sys.executable, "-c", CHECK], cwd=ROOT, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def _require_cpu(device):
    if device != "cpu":
        pytest.skip("the reference file holds CPU fp64 outputs")


def test_outputs_match_committed_reference(device):
    _require_cpu(device)
    got = _check(pinned_blas_env(dict(os.environ)))
    assert not got["bad"], "outputs changed:\n" + "\n".join(got["bad"][:20])
    if got["blas"] == recorded_blas():  # the pin took: the same kernels give the same bits
        assert not got["within"], "outputs changed in the last bits under the recorded BLAS:\n" + "\n".join(got["within"][:20])


def _openblas_x86() -> bool:
    return platform.machine() in ("x86_64", "AMD64") and all("openblas" in d["library"] for d in recorded_blas() or [{}])


@pytest.mark.slow
def test_another_blas_kernel_set_stays_within_round_off(device):
    """Prescott's SSE3 kernels (which every x86-64 CPU runs) give other last bits than the recorded
    set: the check passes on its tolerances and did use them."""
    _require_cpu(device)
    if not _openblas_x86():
        pytest.skip("OpenBLAS kernel sets are x86-64's")
    got = _check(dict(os.environ, OPENBLAS_CORETYPE="Prescott", OPENBLAS_NUM_THREADS="1"))
    assert not got["bad"], "\n".join(got["bad"][:20])
    assert got["within"], "Prescott's kernels gave the recorded bits: this test no longer exercises the tolerances"
    assert any(k.endswith("/strain") for k in got["within"])


def test_the_tolerances_catch_a_change_far_below_physics(device):
    """A cable stiffness changed by 1e-8 (a real change, a million times below the 1.05 perturbations
    the physics checks catch) is over the tolerance of the holdout column's histories."""
    _require_cpu(device)
    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch

    cfg = ColumnConfig(n_prisms=4)
    ea = np.pi * cfg.cable_radius ** 2 * cfg.cable_modulus
    outs = {}
    for scale in (1.0, 1.0 + 1e-8):  # the holdout scene column_b0.0_rattle of benchmarks/reference_outputs.py
        r = simulate_batch(cfg, {"prestrain": [0.002], "v0": [0.05], "base_rigidity": [0.0], "cable_EA": [ea * scale]},
                           RunSettings(t_end=0.2, dt=2e-4, method="rattle", output_interval=0.01, device="cpu"))
        outs[scale] = {f"column_b0.0_rattle/{k}": np.asarray(getattr(r, k)) for k in ("strain", "kinetic_energy")}
    for scale, arrays in outs.items():
        bad = [b for b in compare_report(arrays, REFERENCE_FILE)[0] if b.startswith("column_b0.0_rattle/")
               and "missing" not in b]
        if scale == 1.0:
            assert not bad, bad  # the same stiffness, given explicitly, is the reference
        else:
            assert any("strain" in b for b in bad) and any("kinetic_energy" in b for b in bad), bad
