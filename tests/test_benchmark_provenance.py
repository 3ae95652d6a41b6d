"""Issue 33 item 6: a committed benchmark result records the commit of the code it measured.

``benchmarks/common.py`` refuses to run from a checkout whose tracked files differ from HEAD
(unless ``WT_BENCH_ALLOW_DIRTY=1``, a trial whose results say '-dirty'), and records ``code_sha256``,
the hash of ``warp_tensegrity/`` and ``benchmarks/`` as measured. On the GPU machine the copy has no
``.git`` and the commit comes from ``GIT_COMMIT``: the hash is what lets this test check that claim
against git.
"""

import json
import os
import subprocess
from pathlib import Path

import pytest

from benchmarks import common

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
LEGACY_DIRTY = {
    # results committed before the rule (issue 33 item 6), measured from uncommitted code: kept as
    # the history they are, not quoted as the code of any commit. Nothing may join this list.
    "contact_cost_cpu.json",
    "default_accuracy_cpu.json",
    "end_to_end_h200_runplan.json",
    "lanes_check_h200.json",
    "lanes_check_n7_cpu.json",
    "lanes_check_n7_n100_h200.json",
    "lanes_h200_dev/lanes_check_h200.json",
    "lanes_h200_dev/lanes_tuning2_h200.json",
    "lanes_h200_dev/lanes_tuning_h200.json",
    "lanes_h200_dev/throughput_lanes_h200.json",
    "lanes_tuning_h200/lanes_tuning_fm_FB.json",
    "lanes_tuning_h200/lanes_tuning_fm_RB.json",
    "lanes_tuning_h200/lanes_tuning_sp_FB.json",
    "lanes_tuning_h200/lanes_tuning_sp_RB.json",
    "peer_mujoco_cpu.json",
    "peer_scipy_cpu.json",
    "staged_tuning_h200.json",
    "staged_tuning_h200_before.json",
    "staged_tuning_h200_window.json",
    "throughput_cpu.json",
    "throughput_cpu_quick.json",
    "throughput_h100_solver_globalnodes.json",
    "throughput_h100_solver_head.json",
    "throughput_lanes_extra_h200.json",
    "throughput_lanes_fb_h200.json",
    "throughput_lanes_h200.json",
    "throughput_lanes_prisms_h200.json",
}


def _claims(obj):
    """Every (commit, code_sha256 or None) a result JSON states, at any depth."""
    if isinstance(obj, dict):
        commit = obj.get("git_commit", obj.get("commit"))
        if isinstance(commit, str):
            yield commit, obj.get("code_sha256")
        for v in obj.values():
            yield from _claims(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _claims(v)


def _results():
    return sorted(p for p in RESULTS.rglob("*.json"))


def test_no_new_result_from_uncommitted_code():
    bad = [str(p.relative_to(ROOT)) for p in _results() if p.relative_to(RESULTS).as_posix() not in LEGACY_DIRTY
           and any(c.endswith("-dirty") for c, _ in _claims(json.loads(p.read_text())))]
    assert not bad, f"results measured from uncommitted code: {bad}"


def test_recorded_code_is_the_code_of_the_recorded_commit():
    shallow = subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=ROOT, capture_output=True,
                             text=True).stdout.strip()
    if shallow == "true":
        pytest.skip("a shallow clone holds no history to check the results' commits against")
    wrong = []
    hashes: dict[str, str] = {}
    for p in _results():
        for commit, sha in set(_claims(json.loads(p.read_text()))):
            if sha is None or commit.endswith("-dirty"):
                continue
            if commit not in hashes:
                hashes[commit] = common.code_hash(commit)
            if hashes[commit] != sha:
                wrong.append(f"{p.relative_to(ROOT)}: commit {commit[:12]} does not hold the code measured")
    assert not wrong, "\n".join(wrong)


def _repo(tmp_path, monkeypatch):
    """A one-commit repository laid out as ours, as benchmarks.common sees it."""
    env = dict(os.environ, GIT_AUTHOR_NAME="t", GIT_AUTHOR_EMAIL="t@t", GIT_COMMITTER_NAME="t",
               GIT_COMMITTER_EMAIL="t@t")
    for d in ("warp_tensegrity", "benchmarks"):
        (tmp_path / d).mkdir()
        (tmp_path / d / "a.py").write_text(f"X = '{d}'\n")
    for cmd in (["init", "-q"], ["add", "."], ["commit", "-qm", "x"]):
        subprocess.run(["git", *cmd], cwd=tmp_path, check=True, env=env)
    monkeypatch.setattr(common, "REPO", tmp_path)
    monkeypatch.delenv("GIT_COMMIT", raising=False)
    monkeypatch.delenv(common.DIRTY_OK, raising=False)
    return subprocess.run(["git", "rev-parse", "HEAD"], cwd=tmp_path, capture_output=True, text=True).stdout.strip()


def test_a_dirty_checkout_is_refused_and_the_hash_tells_code_apart(tmp_path, monkeypatch):
    head = _repo(tmp_path, monkeypatch)
    assert common.git_commit() == head
    assert common.code_hash() == common.code_hash(head)  # the working tree against git's copy
    (tmp_path / "warp_tensegrity" / "a.py").write_text("X = 2\n")
    with pytest.raises(SystemExit, match="tracked files differ from commit"):
        common.git_commit()
    assert common.code_hash() != common.code_hash(head)  # what the results test would catch
    monkeypatch.setenv(common.DIRTY_OK, "1")
    assert common.git_commit() == head + "-dirty"
    monkeypatch.setenv("GIT_COMMIT", head)  # the GPU machine's claim, checked by the hash afterwards
    assert common.git_commit() == head
