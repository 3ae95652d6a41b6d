"""Shards on disk: the manifest, the state of each shard file, preparing the shard directory,
combining the shards and the status of a run.


Files for ``OUT.nc``::

    OUT.nc.shards/manifest.json     what the shards belong to (fingerprint, shard size, device)
    OUT.nc.shards/spec.toml         the spec text (so ``resume OUT.nc`` needs nothing else)
    OUT.nc.shards/shard-00000.nc    columns [0, shard_size), ...
    OUT.nc                          the combined dataset

A shard is reused only when it opens cleanly, covers the same columns, carries the same
fingerprint (canonical spec + code version) and was made with the same Warp version;
every other shard is recomputed. The engine is called only through :func:`simulate_batch`.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from .. import io as D
from ..provenance import warp_version
from ..types import ShardState, Status
from .errors import SweepError

if TYPE_CHECKING:
    from .plan import SweepPlan

MANIFEST = "manifest.json"
SPEC_COPY = "spec.toml"


def shard_dir_for(out) -> Path:
    out = Path(out)
    return out.with_name(out.name + ".shards")


def shard_name(index: int) -> str:
    return f"shard-{index:05d}.nc"


@dataclass
class ShardCheck:
    """What :func:`check_shard` found for one shard file."""

    index: int
    path: Path
    state: ShardState
    reason: str = ""
    n_failed: int = 0
    n_columns: int = 0


def check_shard(plan: SweepPlan, index: int) -> ShardCheck:
    path = plan.shard_path(index)
    start, stop = plan.shards[index]
    if not path.exists():
        return ShardCheck(index, path, ShardState.MISSING, n_columns=stop - start)
    try:
        ds = D.open_sweep(path, load=True)
    except Exception as e:  # truncated or not netCDF at all
        return ShardCheck(index, path, ShardState.CORRUPT, f"{type(e).__name__}: {e}", n_columns=stop - start)
    a = ds.attrs
    reason = ""
    if a.get("fingerprint") != plan.fingerprint:
        reason = "fingerprint differs (spec or code changed)"
    elif (int(a.get("case_start", -1)), int(a.get("case_stop", -1))) != (start, stop):
        reason = f"covers columns {a.get('case_start')}:{a.get('case_stop')}, expected {start}:{stop}"
    elif a.get("warp_version") != warp_version():
        reason = f"made with Warp {a.get('warp_version')}, this is Warp {warp_version()}"
    elif ds.sizes.get("case") != stop - start or "status" not in ds:
        reason = "incomplete contents"
    if reason:
        return ShardCheck(index, path, ShardState.STALE, reason, n_columns=stop - start)
    return ShardCheck(index, path, ShardState.DONE, n_failed=int((ds["status"].values != Status.OK).sum()), n_columns=stop - start)


def _clean_tmp(shard_dir: Path) -> None:
    for p in shard_dir.glob(".*.tmp"):
        try:
            p.unlink()
        except OSError:
            pass


def _write_manifest(plan: SweepPlan) -> None:
    d = plan.shard_dir
    d.mkdir(parents=True, exist_ok=True)
    (d / f".{SPEC_COPY}.tmp").write_text(plan.spec.text)
    os.replace(d / f".{SPEC_COPY}.tmp", d / SPEC_COPY)
    manifest = {
        "spec_file": str(plan.spec.source) if plan.spec.source else None,
        "spec_sha256": plan.spec.text_sha256,
        "fingerprint": plan.fingerprint,
        "code_version": plan.code_version,
        "n_columns": plan.n_columns,
        "shard_size": plan.shard_size,
        "n_shards": plan.n_shards,
        "device": plan.device,
        "output": plan.out.name,
    }
    tmp = d / f".{MANIFEST}.tmp"
    tmp.write_text(json.dumps(manifest, indent=2) + "\n")
    os.replace(tmp, d / MANIFEST)


def read_manifest(out) -> dict:
    d = shard_dir_for(out)
    if not d.is_dir():
        raise SweepError(f"no run found for {out}: {d}/ does not exist (start one with `warp-tensegrity run SPEC -o {out}`)")
    try:
        manifest = json.loads((d / MANIFEST).read_text())
        text = (d / SPEC_COPY).read_text()
    except (OSError, ValueError) as e:
        raise SweepError(
            f"{d} has no readable {MANIFEST}/{SPEC_COPY} ({e}); give the spec: resume SPEC -o {out}"
        ) from None
    manifest["spec_text"] = text
    return manifest


def prepare_dir(plan: SweepPlan, overwrite: bool, resume: bool) -> None:
    d = plan.shard_dir
    if d.exists() and not resume:
        existing = sorted(d.glob("shard-*.nc"))
        if existing or (d / MANIFEST).exists():
            if not overwrite:
                raise SweepError(
                    f"{d} already holds a run ({len(existing)} shard files); continue it with "
                    f"`warp-tensegrity resume {plan.out}` or start over with --overwrite"
                )
            for p in existing + [d / MANIFEST, d / SPEC_COPY]:
                if p.exists():
                    p.unlink()
    if not resume and plan.out.exists():
        if not overwrite:
            raise SweepError(f"{plan.out} exists; give another output, or --overwrite to replace it")
        plan.out.unlink()
    d.mkdir(parents=True, exist_ok=True)
    _clean_tmp(d)
    _write_manifest(plan)


def status_from_output(out) -> dict:
    """Status of a combined output whose shard directory is gone."""
    try:
        ds = D.open_sweep(out)
    except Exception as e:
        raise SweepError(f"{out} does not open ({type(e).__name__}: {e}) and has no shard directory") from None
    n = int(ds.attrs.get("n_columns", ds["status"].size))
    return {
        "output": str(out),
        "spec": ds.attrs.get("spec_file"),
        "columns": n,
        "shards": 0,
        "shard_size": 0,
        "shards_done": 0,
        "cases_done": n,
        "cases_diverged": int((ds["status"].values != Status.OK).sum()),
        "cases_remaining": 0,
        "shards_missing": [],
        "shards_stale": [],
        "shards_corrupt": [],
        "combined": True,
        "fingerprint": ds.attrs.get("fingerprint"),
    }
