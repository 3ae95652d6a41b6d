"""The state of a whole sweep, read back: which shards are done, stale or corrupt, how many
columns are left, whether the netCDF export is current; and what ``resume OUT.nc`` needs from a
run's work directory (:mod:`.store` describes the files)."""

from __future__ import annotations

import hashlib

import numpy as np
import xarray as xr

from .. import io as D
from ..types import ShardState, Status
from .errors import SweepError
from .manifest import SPEC_COPY, Manifest
from .store import SweepStore


def shard_states(store: SweepStore, plan, verify: bool = True) -> list[tuple[int, str, str]]:
    """(index, state, reason) per shard: state 'done', 'missing', 'stale' or 'corrupt'."""
    group = None
    if verify and store.manifest is not None and store.manifest.shards:
        import zarr

        try:
            group = zarr.open_group(str(store.zarr), mode="r")
        except Exception:
            group = None
    out = []
    for i in range(plan.n_shards):
        if not verify:
            recorded = str(i) in (store.manifest.shards if store.manifest else {})
            out.append((i, ShardState.DONE if recorded else ShardState.MISSING, ""))
            continue
        state, why = store.verify_shard(plan, i, group)
        out.append((i, state, why))
    return out


def status(plan, time: np.ndarray) -> dict:
    """Columns done, diverged and remaining; shards verified against their checksums (``time``:
    the plan's output times, those of :func:`~warp_tensegrity.sweep.shard.template_dataset`)."""
    store = SweepStore(plan.out)
    manifest = None
    why = "no store"
    if store.exists():
        manifest, why = store.open(plan, time)
    if manifest is None:
        states = [(i, ShardState.MISSING, "") for i in range(plan.n_shards)]
        if store.exists():  # a readable manifest of another spec/code/layout: stale; else corrupt
            kind = ShardState.STALE if Manifest.read(store.manifest_path)[0] is not None else ShardState.CORRUPT
            states = [(i, kind, why) for i in range(plan.n_shards)]
    else:
        states = shard_states(store, plan)
    done = [i for i, s, _ in states if s == ShardState.DONE]
    cols = sum(plan.shards[i][1] - plan.shards[i][0] for i in done)
    exported = False
    if plan.out.exists():
        try:
            with xr.open_dataset(plan.out, engine="netcdf4") as ds:
                exported = ds.attrs.get("fingerprint") == plan.fingerprint
        except Exception:
            exported = False
    return {
        "output": str(plan.out),
        "store": str(store.dir),
        "spec": plan.spec.source,
        "columns": plan.n_columns,
        "shards": plan.n_shards,
        "shard_size": plan.shard_size,
        "shards_done": len(done),
        "cases_done": cols,
        "cases_diverged": sum(int(manifest.shards[str(i)]["n_failed"]) for i in done) if manifest else 0,
        "cases_remaining": plan.n_columns - cols,
        "shards_missing": [i for i, s, _ in states if s == ShardState.MISSING],
        "shards_stale": [(i, r) for i, s, r in states if s == ShardState.STALE],
        "shards_corrupt": [(i, r) for i, s, r in states if s == ShardState.CORRUPT],
        "combined": exported and len(done) == plan.n_shards,
        "fingerprint": plan.fingerprint,
    }


def read_run(out) -> dict:
    """What ``resume OUT.nc`` needs: the spec text and the manifest header (if it checks out)."""
    store = SweepStore(out)
    if not store.dir.is_dir():
        raise SweepError(f"no run found for {out}: {store.dir}/ does not exist "
                         f"(start one with `warp-tensegrity run SPEC -o {out}`)")
    try:
        text = (store.dir / SPEC_COPY).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise SweepError(f"{store.dir} has no readable {SPEC_COPY} ({e}); give the spec: resume SPEC -o {out}") from None
    content, _ = Manifest.read(store.manifest_path)
    if content is None:  # the manifest is gone or damaged: the spec's path is also in the store's attributes
        try:
            src = xr.open_zarr(store.zarr, consolidated=False).attrs.get("spec_source", "none")
            content = {"spec_file": None if src == "none" else src,
                       "spec_sha256": hashlib.sha256(text.encode()).hexdigest()}
        except Exception:
            content = None
    content = dict(content or {})
    if content and content.get("spec_sha256") != hashlib.sha256(text.encode()).hexdigest():
        content = {}  # the spec copy is not the one the manifest recorded: trust neither header nor shards
    content["spec_text"] = text
    return content


def shards_to_run(plan) -> list[int]:
    """Shards a resume of ``plan`` would run, by its manifest (not re-verified: what the estimate of
    a resume prices; ``resume`` itself checks every recorded shard): all of them when the store was
    made for another fingerprint or shard size, or has no manifest."""
    try:
        content = read_run(plan.out)
    except SweepError:
        return list(range(plan.n_shards))
    if content.get("fingerprint") != plan.fingerprint or content.get("shard_size") != plan.shard_size:
        return list(range(plan.n_shards))
    done = {int(i) for i in content.get("shards", {})}
    return [i for i in range(plan.n_shards) if i not in done]


def status_from_output(out) -> dict:
    """Status of an exported netCDF output whose store is gone (deleted after the run)."""
    try:
        ds = D.open_sweep(out)
    except Exception as e:
        raise SweepError(f"{out} does not open ({type(e).__name__}: {e}) and has no store") from None
    if "status" not in ds.variables or "fingerprint" not in ds.attrs:
        what = ds.attrs.get("title") or ds.attrs.get("source") or "no title"
        raise SweepError(f"{out} is not the output of a sweep (`warp-tensegrity run`): it has no "
                         f"{'status variable' if 'status' not in ds.variables else 'fingerprint attribute'} "
                         f"({what}); status, combine and resume read sweep outputs")
    n = int(ds.attrs.get("n_columns", ds["status"].size))
    return {
        "output": str(out), "store": None, "spec": ds.attrs.get("spec_file"), "columns": n, "shards": 0,
        "shard_size": 0, "shards_done": 0, "cases_done": n,
        "cases_diverged": int((ds["status"].values != Status.OK).sum()), "cases_remaining": 0,
        "shards_missing": [], "shards_stale": [], "shards_corrupt": [], "combined": True,
        "fingerprint": ds.attrs.get("fingerprint"),
    }
