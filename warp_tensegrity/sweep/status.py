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
from .manifest import SPEC_COPY, Manifest, StoreError
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
    had_manifest = store.manifest_path.exists()  # before the read: a manifest that appears meanwhile is read
    if store.exists():
        manifest, why = store.open(plan, time)
    if manifest is None:
        states = [(i, ShardState.MISSING, "") for i in range(plan.n_shards)]
        if store.exists() and had_manifest:  # a readable manifest of another spec/code/layout: stale; else corrupt
            kind = ShardState.STALE if Manifest.read(store.manifest_path)[0] is not None else ShardState.CORRUPT
            states = [(i, kind, why) for i in range(plan.n_shards)]
        # no manifest yet: a run is initialising the store (or stopped while it did): nothing is done
    else:
        states = shard_states(store, plan)
    done = [i for i, s, _ in states if s == ShardState.DONE]
    cols = sum(plan.shards[i][1] - plan.shards[i][0] for i in done)
    exported = plan.out.exists() and output_fingerprint(plan.out) == plan.fingerprint
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


def output_fingerprint(out) -> str | None:
    """The ``fingerprint`` attribute of a netCDF output (None: it does not open, or has none)."""
    try:
        with xr.open_dataset(out, engine="netcdf4") as ds:
            return ds.attrs.get("fingerprint")
    except Exception:  # not netCDF, truncated, unreadable: not a sweep's export
        return None


def recorded_header(out) -> dict:
    """The manifest's header of the run at ``out`` ({} when there is no manifest that checks out)."""
    content, _ = Manifest.read(SweepStore(out).manifest_path)
    return content or {}


def read_run(out) -> dict:
    """What ``resume OUT.nc`` needs: the spec text and the manifest header. A spec copy that is not
    the one the manifest recorded (edited or damaged) is refused (StoreError): its shards were
    verified against another spec."""
    store = SweepStore(out)
    if not store.dir.is_dir():
        raise SweepError(f"no run found for {out}: {store.dir}/ does not exist "
                         f"(start one with `warp-tensegrity run SPEC -o {out}`)")
    try:
        text = (store.dir / SPEC_COPY).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        how = f"({e})" if not isinstance(e, FileNotFoundError) or store.manifest_path.exists() else \
            "(a run is initialising the store, or stopped before it wrote the copy)"
        raise SweepError(f"{store.dir} has no readable {SPEC_COPY} {how}; give the spec: "
                         f"`warp-tensegrity resume SPEC -o {out}`") from None
    sha = hashlib.sha256(text.encode()).hexdigest()
    content, _ = Manifest.read(store.manifest_path)
    if content is None:  # the manifest is gone or damaged: the spec's path is also in the store's attributes
        try:
            import zarr

            src = zarr.open_group(str(store.zarr), mode="r").attrs.get("spec_source", "none")
            content = {"spec_file": None if src == "none" else src, "spec_sha256": sha}
        except Exception:  # no store.zarr, or its metadata damaged
            content = None
    content = dict(content or {})
    if content and content.get("spec_sha256") != sha:
        raise StoreError(
            f"{store.dir / SPEC_COPY} is not the spec its manifest recorded (sha256 {sha[:12]}, recorded "
            f"{str(content.get('spec_sha256'))[:12]}): the copy was edited or damaged, so the store's shards "
            f"cannot be matched to it. Give the run's spec: `warp-tensegrity resume SPEC -o {out}` (finished "
            f"shards are reused and the copy restored), or start over: `warp-tensegrity run SPEC -o {out} --overwrite`")
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
