"""Drive a sweep: plan the shards (or re-plan them from a run's manifest), run each shard that is
not done (here, pipelined with a writer thread, or on Dask workers) into the sweep's Zarr store,
export netCDF from it, and report a run's status (:mod:`.store` describes the files)."""

from __future__ import annotations

import hashlib
import logging
import math
import threading
from pathlib import Path

import xarray as xr

from ..engine import HostWork
from ..outputs import check_output_file
from ..types import ShardState
from .dask import run_shards_dask
from .errors import SweepError
from .manifest import SPEC_COPY, STORE, Manifest, StoreError, SweepLock, _atomic_write_text, fault
from .plan import SweepPlan, decide_sweep, plan_sweep
from .progress import ProgressBar
from .shard import compute_and_write, compute_shard, template_dataset
from .spec import SweepSpec, load_spec
from .status import output_fingerprint, read_run, recorded_header, shard_states, status, status_from_output
from .store import ShardWriter, SweepStore, _header, _log, export_netcdf, time_coord

log = logging.getLogger(__name__)


def execute(
    plan: SweepPlan,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool | None = None,
    dask_workers: int | None = None,
    scheduler: str | None = None,
    client=None,
    stream=None,
    combine_output: bool = True,
    keep_store: bool = True,
    cost: dict | None = None,
) -> Path | None:
    """Run (or resume) every shard of ``plan`` that is not done into the store, then export plan.out.
    ``progress``: None shows the bar only when ``stream`` (stderr) is a terminal; True always; False never.

    Holds the output's lock throughout. A run refuses an existing output or store without
    ``overwrite``; a resume re-reads every recorded shard and recomputes those that do not check out.
    No command replaces finished work without ``overwrite``: a resume refuses a store with
    finished shards of another run (spec, code, shard size or output times), or an output that
    is not this run's; a resume of a finished, exported run does nothing.
    ``keep_store`` False removes the store (``OUT.nc.sweep/``) once ``OUT.nc`` is written: the
    output stays complete and ``status`` still reads it, but ``combine`` and ``resume`` have
    nothing left to work from. ``cost``: the run's predicted cost
    (:func:`warp_tensegrity.policy.calibrate.estimate_plan`), the progress bar's first ETA.
    """
    if plan.out is None:
        raise SweepError("no output path")
    if plan.run is None:
        decide_sweep(plan)
    store = SweepStore(plan.out)
    layout = None  # the template and the store's layout, when they step with the first shard (HostWork)
    if plan.memory_limit:
        import zarr

        # Zarr's codec threads each keep a malloc arena (~2 MB apiece measured): one is enough when
        # memory is tight. Global, and fixed once Zarr first writes in this process.
        zarr.config.set({"threading.max_workers": 1})
    # a fresh run on a GPU builds its template and lays out its store while the first shard steps
    deferred = not resume and layout_with_first_shard(plan, serial=not (dask_workers or scheduler or client is not None))
    with SweepLock(plan.out):
        tpl = None if deferred else template_dataset(plan)
        time = plan.run.output_times if deferred else time_coord(tpl)  # the template's time coordinate
        check_output(plan.out, resume=resume, overwrite=overwrite)  # under the lock: what is there now
        if not resume and (store.exists() or plan.out.exists()):
            store.remove()  # check_output let it through: overwrite
            plan.out.unlink(missing_ok=True)
        if store.dir.exists():
            store.clean_tmp()
        manifest, why = store.open(plan, time) if resume else (None, "")
        if resume and not overwrite:
            _refuse_to_replace(store, plan, time, manifest is not None)
        if manifest is None:
            if resume:
                if plan.out.exists() and not store.exists() and output_fingerprint(plan.out) == plan.fingerprint:
                    _log(f"{plan.out} is complete (its store was removed): nothing to resume", stream)
                    return plan.out
                if store.exists():
                    _log(f"{store.dir}: {why}; recomputing every shard", stream)
            states = [(i, ShardState.MISSING, "") for i in range(plan.n_shards)]
            if deferred:
                # two turns of the host while the first shard's runs step: the template, then the
                # store laid out from it
                layout = HostWork(_lay_out(store, plan), "write")
            else:
                manifest = store.initialise(plan, tpl)
        else:
            _restore_spec_copy(store, plan, stream)
            states = shard_states(store, plan)
            bad = [(i, s, r) for i, s, r in states if s in (ShardState.STALE, ShardState.CORRUPT)]
            for i, s, r in bad:
                _log(f"shard {i} is {s} ({r}); recomputing it", stream)
                manifest.shards.pop(str(i), None)
            if bad:
                manifest.save()
        done = [i for i, s, _ in states if s == ShardState.DONE]
        todo = [i for i, s, _ in states if s != ShardState.DONE]
        if resume and not todo and plan.out.exists() and output_fingerprint(plan.out) == plan.fingerprint:
            _log(f"{plan.out} is complete: nothing to resume (`warp-tensegrity combine {plan.out}` exports it again)",
                 stream)
            return plan.out
        tally = {"cols": sum(plan.shards[i][1] - plan.shards[i][0] for i in done),
                 "failed": sum(int(manifest.shards[str(i)]["n_failed"]) for i in done)}
        bar = ProgressBar(plan.n_columns, tally["cols"], tally["failed"], stream=stream, enabled=progress,
                          estimate_s=_estimated_seconds(plan, todo, cost))
        log.debug("%d of %d shards to run (%d columns done)", len(todo), plan.n_shards, tally["cols"])
        lk = threading.Lock()

        def on_done(i, rec):
            a, b = plan.shards[i]
            with lk:
                tally["cols"] += b - a
                tally["failed"] += int(rec["n_failed"])
                bar.update(tally["cols"], tally["failed"], force=True)

        if todo and (dask_workers or scheduler or client is not None):
            def on_result(i, rec):
                manifest.mark_done(i, rec)
                on_done(i, rec)

            run_shards_dask(plan, todo, compute_and_write, n_workers=dask_workers, scheduler=scheduler,
                            client=client, on_result=on_result)
        elif todo:
            writer = ShardWriter(store, plan, time, on_done)
            try:
                for i in todo:
                    writer.acquire()  # at most IN_FLIGHT shards alive: this one steps while one is written
                    n = plan.shards[i][1] - plan.shards[i][0]

                    def cb(steps_done, n_steps, n_failed, _n=n):
                        fault("stepping")
                        frac = steps_done / n_steps if n_steps else 1.0
                        with lk:
                            bar.update(tally["cols"] + _n * frac, tally["failed"] + n_failed)

                    ds = compute_shard(plan, i, progress=cb, host=[layout] if layout is not None else [])
                    if layout is not None:
                        (tpl, manifest), layout = layout.value, None
                    writer.submit(i, ds)
                    del ds
            finally:
                writer.close()
        if todo:
            manifest.save()  # the journal folded into manifest.json: one file again
        bar.close()
        if not combine_output:
            return None
        fault("finalise")
        export_netcdf(store.dataset(plan, tpl), plan.out, whole=plan.n_shards == 1)
        if not keep_store:
            store.remove()
    return plan.out


def layout_with_first_shard(plan: SweepPlan, serial: bool) -> bool:
    """Whether a fresh run builds its template and lays out its store while its first shard steps: a
    run here (not on Dask workers, whose client writes the layout before any task) on a GPU."""
    return bool(serial and plan.run.on_gpu and plan.n_shards)


def _lay_out(store: SweepStore, plan: SweepPlan):
    """A fresh store laid out from the plan's template dataset, as a HostWork generator of two turns
    (the template, then the layout: 1.7-1.9 s and 0.8 s for phase_large on an H200's host), taken
    while the runs' chunks, all queued in their first turns, step; a run whose work has ended is
    resumed between the two. Returns (template, manifest)."""
    tpl = template_dataset(plan)
    yield
    return tpl, store.initialise(plan, tpl)


def check_output(out: Path, *, resume: bool = False, overwrite: bool = False) -> None:
    """Refuse, before anything is computed: an earlier run's store (a run without ``overwrite``),
    and whatever :func:`check_output_file` refuses."""
    store = SweepStore(out)
    if not resume and not overwrite and store.exists():
        raise StoreError(f"{store.dir} already holds a run; continue it with `warp-tensegrity resume {out}`, "
                         f"give another output, or start over with --overwrite")
    check_output_file(out, exists_ok=resume or overwrite)


def _difference(content: dict, plan: SweepPlan, time) -> str | None:
    """What makes a store's manifest ``content`` another run than ``plan``, in words (None: the same run)."""
    want = _header(plan, time)
    if content.get("spec_sha256") != want["spec_sha256"]:
        return (f"its spec differs (sha256 {str(content.get('spec_sha256'))[:12]} recorded, this one "
                f"{want['spec_sha256'][:12]})")
    if content.get("code_version") != want["code_version"]:
        return f"it was made by code {content.get('code_version')}, this is {want['code_version']}"
    if content.get("shard_size") != want["shard_size"]:
        return (f"its shard size is {content.get('shard_size')}, this run's {want['shard_size']} "
                f"(--shard-size, --memory-limit)")
    for k, v in want.items():
        if k not in ("spec_file", "output", "device") and content.get(k) != v:
            return f"it was made with {k} = {content.get(k)!r}, this run has {v!r}"
    return None


def _refuse_to_replace(store: SweepStore, plan: SweepPlan, time, store_ok: bool) -> None:
    """Refuse a resume that would discard finished work of another run: done shards recorded for
    another spec, code or layout (the store does not open for ``plan``: not ``store_ok``), or an
    output that is not this run's export. This run's own shards in a damaged store (a manifest
    that fails its checksum, chunks that do not open) are recomputed."""
    content = None if store_ok else Manifest.read(store.manifest_path)[0]
    diff = _difference(content, plan, time) if content and content.get("shards") else None
    if diff:
        n = len(content["shards"])
        raise StoreError(
            f"{store.dir} holds {n} finished shard{'' if n == 1 else 's'} of another run: {diff}. resume keeps "
            f"finished work: give that run's spec and options (`warp-tensegrity resume {plan.out}` takes those "
            f"it recorded), or discard it with --overwrite")
    if plan.out.exists() and output_fingerprint(plan.out) != plan.fingerprint:
        raise StoreError(f"{plan.out} exists and is not this run's export (another run's output, or not a "
                         f"sweep's); give another output, or replace it with --overwrite")


def _restore_spec_copy(store: SweepStore, plan: SweepPlan, stream=None) -> None:
    """Rewrite the store's spec copy when it is not the spec its manifest recorded (edited or
    damaged; the manifest checked out against ``plan``, whose spec is the recorded one)."""
    path = store.dir / SPEC_COPY
    try:
        ok = hashlib.sha256(path.read_bytes()).hexdigest() == plan.spec.text_sha256
    except OSError:
        ok = False
    if not ok:
        _log(f"{path} was not the spec its manifest recorded: restored from {plan.spec.source or 'the spec given'}",
             stream)
        _atomic_write_text(path, plan.spec.text)


def _estimated_seconds(plan: SweepPlan, todo, cost: dict | None) -> float | None:
    """The cost model's stepping and measuring time for the shards still to run (None if unknown)."""
    if cost is None:
        return None
    st = cost["stages_s"]
    secs = (st["stepping"] + st["measurement"]) * sum(plan.shards[i][1] - plan.shards[i][0] for i in todo) / plan.n_columns
    return secs if math.isfinite(secs) and secs > 0 else None


def run_sweep(spec, out, *, device=None, shard_size=None, resume=False, overwrite=False, progress=None,
              dask_workers=None, scheduler=None, client=None, stream=None, memory_limit=None,
              keep_store=True) -> Path:
    """Run a spec (SweepSpec, path or TOML text) into ``out`` (netCDF, exported from ``out.sweep/``).
    ``memory_limit`` (bytes or '512MB') lowers the shard size so the host holds at most that much
    sweep data (see docs/guarantees.md). ``keep_store`` False: the store is removed once ``out``
    is written (see :func:`execute`)."""
    if not isinstance(spec, SweepSpec):
        spec = load_spec(spec)
    plan = plan_sweep(spec, out, device=device, shard_size=shard_size, memory_limit=memory_limit)
    return execute(plan, resume=resume, overwrite=overwrite, progress=progress, dask_workers=dask_workers,
                   scheduler=scheduler, client=client, stream=stream, keep_store=keep_store)


def resume_sweep(out, spec=None, *, device=None, shard_size=None, progress=None, dask_workers=None,
                 scheduler=None, client=None, stream=None, keep_store=True, overwrite=False) -> Path:
    """Finish an interrupted run: reuse the shards that check out, recompute the others, export.
    Refuses finished work of another run (a store made for another spec, code or shard size, or an
    output that is not this run's) unless ``overwrite``; a finished, exported run is left as it is."""
    if spec is None:
        plan = load_plan_from_manifest(out, device=device, shard_size=shard_size)
    else:
        if not isinstance(spec, SweepSpec):
            spec = load_spec(spec)
        plan = plan_sweep(spec, out, device=device, shard_size=shard_size or recorded_header(out).get("shard_size"))
    return execute(plan, resume=True, overwrite=overwrite, progress=progress, dask_workers=dask_workers,
                   scheduler=scheduler, client=client, stream=stream, keep_store=keep_store)


def load_plan_from_manifest(out, *, device=None, shard_size=None, estimate=True, memory_limit=None) -> SweepPlan:
    """The plan of the run at ``out``, from its spec copy and manifest header."""
    return _plan_from_run(out, read_run(out), device=device, shard_size=shard_size, estimate=estimate,
                          memory_limit=memory_limit)


def _plan_from_run(out, m: dict, *, device=None, shard_size=None, estimate=True, memory_limit=None) -> SweepPlan:
    """The plan of the run at ``out`` from :func:`~.status.read_run`'s ``m``."""
    spec = load_spec(m["spec_text"])
    if m.get("spec_file"):
        spec.source = m["spec_file"]
    return plan_sweep(
        spec,
        out,
        device=device if device is not None else m.get("device"),
        shard_size=shard_size or m.get("shard_size"),
        estimate=estimate,
        memory_limit=memory_limit,
    )


def _plan_for(plan_or_out, spec=None) -> SweepPlan:
    if isinstance(plan_or_out, SweepPlan):
        return plan_or_out
    if spec is None:
        return load_plan_from_manifest(plan_or_out)
    return plan_sweep(spec if isinstance(spec, SweepSpec) else load_spec(spec), plan_or_out)


def combine(plan_or_out, spec=None) -> Path:
    """(Re-)export a finished run's store to its netCDF output (the ``combine`` command). Every shard
    is verified against its checksums first: refuses while any is not done or does not check out."""
    plan = _plan_for(plan_or_out, spec)
    store = SweepStore(plan.out)
    with SweepLock(plan.out):
        tpl = template_dataset(plan)
        st = status(plan, time_coord(tpl))
        bad = st["shards_missing"] + [i for i, _ in st["shards_stale"] + st["shards_corrupt"]]
        if bad:
            why = "; ".join(f"shard {i}: {r}" for i, r in (st["shards_stale"] + st["shards_corrupt"])[:4])
            raise StoreError(f"{len(bad)} of {plan.n_shards} shards of {plan.out} are not done or do not check out"
                             f"{' (' + why + ')' if why else ''}; run `warp-tensegrity resume {plan.out}`")
        return export_netcdf(store.dataset(plan, tpl), plan.out, whole=plan.n_shards == 1)


def sweep_status(out, spec=None) -> dict:
    """Cases done, diverged and remaining, per shard state (shards verified against their checksums)."""
    if spec is None and not isinstance(out, SweepPlan) and not SweepStore(out).dir.exists() and Path(out).exists():
        return status_from_output(out)
    if spec is not None or isinstance(out, SweepPlan):
        plan = _plan_for(out, spec)
        return status(plan, time_coord(template_dataset(plan)))
    m = read_run(out)
    plan = _plan_from_run(out, m)
    st = status(plan, time_coord(template_dataset(plan)))
    if "shard_size" not in m and SweepStore(out).manifest_path.exists():
        # planned with the spec's shard size for want of a manifest, which a run initialising the
        # store has written since: plan again from it (its --shard-size may differ from the spec's)
        plan = load_plan_from_manifest(out)
        st = status(plan, time_coord(template_dataset(plan)))
    return st


def open_sweep(path, partial: bool = False) -> xr.Dataset:
    """A sweep as a lazy, dask-backed dataset, in the layout of its netCDF export. ``path``: a run's
    output ``OUT.nc`` (read from its store ``OUT.nc.sweep/`` when there is one), that work
    directory, or any netCDF file. ``partial``: a store whose shards are not all done, case-stacked."""
    path = Path(path)
    if path.name == STORE:
        path = path.parent
    if path.suffix == ".sweep" and path.is_dir():
        path = path.with_name(path.name[: -len(".sweep")])
    store = SweepStore(path)
    if store.manifest_path.exists() or store.dir.is_dir():
        plan = load_plan_from_manifest(path)
        return store.dataset(plan, template_dataset(plan), partial=partial)
    return xr.open_dataset(path, engine="netcdf4", decode_timedelta=False, chunks={})

