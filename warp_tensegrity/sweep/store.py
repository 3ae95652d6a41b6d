"""The streaming sweep store: shards write into one chunked Zarr store as they finish; no combine pass.
(:mod:`.run` drives it; :mod:`.shard` writes one shard from a Dask worker; :mod:`.manifest` holds
the manifest, checksums, lock and atomic writes; :mod:`.status` reports a run from them.)

Files for ``OUT.nc``::

    OUT.nc.sweep/store.zarr      case-stacked Zarr store; one chunk along ``case`` per shard
    OUT.nc.sweep/manifest.json   header (fingerprint, shard size, ...) and the done shards with
                                 their checksums; the manifest carries its own sha256
    OUT.nc.sweep/manifest.journal  a line per shard done since manifest.json was rewritten whole
    OUT.nc.sweep/spec.toml       the spec text (``resume OUT.nc`` needs nothing else)
    .OUT.nc.lock                 held while a run/resume/export writes (filelock)
    OUT.nc                       netCDF export, written from the store chunk by chunk

A shard is visible only when complete: its region of the store is written (each chunk file
replaced atomically by Zarr's LocalStore), the chunk files fsync'd, and only then is the shard
recorded as done, with a sha256 per variable, in the manifest's journal (one line appended, fsync).
Every temporary is created exclusively and never through a link (:mod:`warp_tensegrity.atomic`).
Resume re-reads every recorded shard and recomputes the ones whose checksums do not match.
See ``docs/guarantees.md`` for what is guaranteed and how each guarantee is tested.
"""

from __future__ import annotations

import hashlib
import json
import queue
import shutil
import sys
import threading
import time as _time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import xarray as xr

from .. import io as D
from ..atomic import free_bytes, is_no_space, oserror_line, remove_tmp, tmp_glob
from ..policy.cost import disk_bytes, fmt_bytes, netcdf_bytes
from ..provenance import warp_version
from ..types import ShardState
from .manifest import (
    FORMAT, MANIFEST, SPEC_COPY, STORE, Manifest, StoreError, _atomic_write_text, _fsync_path, array_sha256, fault,
    work_dir_for,
)

IN_FLIGHT = 2
"""Shards alive on the host at once in a serial run: one stepping, one being written."""
FSYNC_THREADS = 16
"""Chunk files of a shard synced at once (:meth:`SweepStore._fsync_chunks`)."""

# ---------------------------------------------------------------------- layout
def time_coord(ds: xr.Dataset) -> np.ndarray:
    """The output-time coordinate of a case-stacked shard (or template, or the store): the one
    dimension that is not ``case``, ``prism`` or ``level`` (a unit_mass profile)."""
    (name,) = [d for d in ds.dims if d not in ("case", "prism", "level")]
    return ds[name].values


def _case_vars(ds: xr.Dataset) -> list[str]:
    return [k for k in ds.data_vars if ds[k].dims[:1] == ("case",)]


def _header(plan, time: np.ndarray) -> dict:
    return {
        "format": FORMAT,
        "fingerprint": plan.fingerprint,
        "code_version": plan.code_version,
        "spec_sha256": plan.spec.text_sha256,
        "spec_file": str(plan.spec.source) if plan.spec.source else None,
        "n_columns": plan.n_columns,
        "shard_size": plan.shard_size,
        "n_shards": plan.n_shards,
        "device": plan.device,
        "output": plan.out.name,
        "time_sha256": array_sha256(time),
        "n_time": int(len(time)),
        # the groups of like stiffness and their dt: a resume under another grouping recomputes
        "groups": [[g.n_columns, float(g.plan.dt), int(g.plan.n_steps)] for g in plan.groups],
        "groups_sha256": array_sha256(plan.column_group),
    }


class SweepStore:
    """One sweep's work directory: the Zarr store, its manifest and the spec copy."""

    def __init__(self, out):
        self.out = Path(out).absolute()
        self.dir = work_dir_for(self.out)
        self.zarr = self.dir / STORE
        self.manifest_path = self.dir / MANIFEST
        self.manifest: Manifest | None = None

    def exists(self) -> bool:
        return self.dir.exists() and (self.manifest_path.exists() or self.zarr.exists())

    def remove(self) -> None:
        if self.dir.is_symlink():  # rmtree would refuse it; what it points to is not this run's
            raise StoreError(f"{self.dir} is a symbolic link, not a store a run made; remove it, or give another output")
        try:
            if self.dir.exists():
                shutil.rmtree(self.dir)
        except OSError as e:
            raise StoreError(oserror_line(e, e.filename or self.dir, "cannot remove")) from None

    def clean_tmp(self) -> None:
        """Remove the temporaries a killed run left: files and private directories (never through a link)."""
        try:
            for p in [*self.out.parent.glob(tmp_glob(self.out)), *self.dir.glob(".*.tmp")]:
                remove_tmp(p)
            if self.zarr.exists():
                for p in self.zarr.rglob("*.partial"):  # a chunk write Zarr did not finish
                    p.unlink(missing_ok=True)
        except OSError as e:
            raise StoreError(oserror_line(e, e.filename, "cannot remove a leftover temporary")) from None

    def write_error(self, e: OSError, plan, path=None) -> StoreError:
        """A write into the store that failed, in one line: the path, the errno and, for a full disk,
        the space the rest of the run needs (the store's shards still to do and the export) and what
        is free; resume continues (every finished shard is kept)."""
        return StoreError(oserror_line(e, path or e.filename or self.dir) + self._what_next(e, plan))

    def _what_next(self, e: OSError, plan) -> str:
        again = f"`warp-tensegrity resume {self.out}` continues (finished shards are kept)"
        if not is_no_space(e):
            return f"; once it can be written, {again}"
        return f"; {self._space_needed(plan)}; free space, then {again}"

    def _space_needed(self, plan) -> str:
        free, where = free_bytes(self.dir)
        try:
            done = set(self.manifest.shards) if self.manifest else set()
            todo = [b - a for i, (a, b) in enumerate(plan.shards) if str(i) not in done]
            r = plan.spec.run
            need = disk_bytes(plan.run, todo, plan.n_columns, plan.n_shards, bool(r["record_strain"]),
                              bool(r["record_energy"]), r["energy_precision"])
        except (AttributeError, KeyError, TypeError):  # a plan without its run decided: no figure
            return f"{fmt_bytes(free)} is free on {where}"
        return (f"the rest of the run needs up to {fmt_bytes(need['total'])} (store {fmt_bytes(need['store'])} + "
                f"{self.out.name} {fmt_bytes(need['netcdf'])}) and {fmt_bytes(free)} is free on {where}")

    # ------------------------------------------------------------------ create / open
    def initialise(self, plan, tpl: xr.Dataset) -> Manifest:
        """A fresh store for ``plan``: coordinates written, data variables empty, no shard done.
        ``tpl``: a one-column shard dataset (:func:`~warp_tensegrity.sweep.shard.template_dataset`),
        whose variables, dims, dtypes and attributes every shard has."""
        try:
            return self._initialise(plan, tpl)
        except OSError as e:
            raise self.write_error(e, plan) from None

    def _initialise(self, plan, tpl: xr.Dataset) -> Manifest:
        import dask.array as da

        self.remove()
        self.dir.mkdir(parents=True)
        time = time_coord(tpl)
        N = plan.n_columns
        extra = (tpl["step"].values,) if "step" in tpl.coords else ()
        layout = plan.spec.layout()
        coords = D._coords(layout, plan.params, 0, N, time, plan.spec.scene.n_prisms, *extra)
        data = {}
        enc = {}
        for k in tpl.data_vars:
            v = tpl[k].variable
            shape = (N,) + v.shape[1:]
            chunks = (min(plan.shard_size, N),) + v.shape[1:]  # one shard wider than the sweep: its columns
            # one dask chunk: to_zarr(compute=False) writes only the metadata, and a chunk per shard
            # would build a graph of a task per shard and variable, never run
            data[k] = xr.Variable(v.dims, da.zeros(shape, dtype=v.dtype, chunks=shape), attrs=dict(v.attrs))
            enc[k] = {"chunks": chunks}
            if k in D.ENERGY_RECORDS and not plan.spec.run.get("compress_energy", True):
                enc[k]["compressors"] = None  # round-off low bits: Zarr's codec would save ~20 % at ~0.5 s per 100 MB
        ds = xr.Dataset(data, coords=coords, attrs={**D.spec_attrs(layout), "fingerprint": plan.fingerprint,
                                                     "spec_source": str(plan.spec.source or "none")})
        for k in ds.coords:
            if ds[k].dtype.kind == "f":
                enc[k] = {"_FillValue": None}
        ds.to_zarr(self.zarr, mode="w", compute=False, encoding=enc, consolidated=False)
        # the spec copy after the store's attributes (spec_source): a copy never lacks its path
        _atomic_write_text(self.dir / SPEC_COPY, plan.spec.text)
        content = _header(plan, time)
        content["coords_sha256"] = {k: array_sha256(coords[k].values) for k in coords}
        content["shards"] = {}
        self.manifest = Manifest(self.manifest_path, content, lambda e: self._what_next(e, plan))
        self.manifest.save()
        return self.manifest

    def open(self, plan, time: np.ndarray) -> tuple[Manifest | None, str]:
        """The manifest if the store belongs to ``plan`` and checks out, else (None, why not)."""
        content, why = Manifest.read(self.manifest_path)
        if content is None:
            return None, why
        want = _header(plan, time)
        for k, v in want.items():
            if k in ("spec_file", "output", "device"):
                continue
            if content.get(k) != v:
                return None, f"store was made with {k} = {content.get(k)!r}, this run has {v!r}"
        if not self.zarr.exists():
            return None, "store.zarr is missing"
        try:
            import zarr

            g = zarr.open_group(str(self.zarr), mode="r")
            for k, sha in content.get("coords_sha256", {}).items():
                if array_sha256(g[k][...]) != sha:
                    return None, f"coordinate {k} does not match its checksum"
        except Exception as e:  # truncated or missing metadata/chunks
            return None, f"store does not open ({type(e).__name__}: {e})"
        self.manifest = Manifest(self.manifest_path, content, lambda e: self._what_next(e, plan))
        return self.manifest, ""

    # ------------------------------------------------------------------ shards
    def verify_shard(self, plan, index: int, group=None) -> tuple[str, str]:
        """('done', '') when shard ``index`` is recorded and its data match the checksums, else
        ('missing' | 'stale' | 'corrupt', why)."""
        rec = self.manifest.shards.get(str(index)) if self.manifest else None
        if rec is None:
            return ShardState.MISSING, ""
        a, b = plan.shards[index]
        if (rec.get("case_start"), rec.get("case_stop")) != (a, b):
            return ShardState.STALE, f"covers columns {rec.get('case_start')}:{rec.get('case_stop')}, expected {a}:{b}"
        if rec.get("attrs", {}).get("warp_version") != warp_version():
            return ShardState.STALE, f"made with Warp {rec.get('attrs', {}).get('warp_version')}, this is Warp {warp_version()}"
        try:
            import zarr

            g = group if group is not None else zarr.open_group(str(self.zarr), mode="r")
            for k, sha in rec["sha256"].items():
                if array_sha256(g[k][a:b]) != sha:
                    return ShardState.CORRUPT, f"{k} does not match its checksum"
        except Exception as e:
            return ShardState.CORRUPT, f"does not read back ({type(e).__name__}: {e})"
        return ShardState.DONE, ""

    def write_shard(self, plan, index: int, ds: xr.Dataset, time: np.ndarray) -> dict:
        """Write shard ``index`` into its region, fsync its chunk files; returns the manifest record
        (the caller marks it done)."""
        a, b = plan.shards[index]
        if ds.sizes.get("case") != b - a:
            raise StoreError(f"shard {index} has {ds.sizes.get('case')} columns, expected {b - a}")
        if array_sha256(time_coord(ds)) != array_sha256(time):
            raise StoreError(
                f"shard {index} has other output times than the store (dt {ds.attrs.get('dt')}); "
                "every shard of a sweep must step with the same dt"
            )
        names = _case_vars(ds)
        sha = {k: array_sha256(ds[k].values) for k in names}
        body = ds[names]
        body = body.drop_vars(list(body.coords))  # the store holds the coordinates (a profile's over level too)
        for v in body.variables.values():
            v.encoding = {}
        region = {"case": slice(a, b)}
        fault("write-begin")
        half = len(names) // 2
        try:
            for part in (names[:half], names[half:]):
                body[part].to_zarr(self.zarr, region=region, mode="r+", consolidated=False)
                fault("mid-write")
            self._fsync_chunks(names, index)
        except OSError as e:
            raise self.write_error(e, plan) from None
        attrs = {k: D._attr(v) for k, v in ds.attrs.items()}
        status = ds["status"].values
        return {"case_start": a, "case_stop": b, "sha256": sha, "n_failed": int(np.count_nonzero(status)),
                "attrs": attrs}

    def _fsync_chunks(self, names, index: int) -> None:
        """fsync the chunk files of shard ``index`` (chunk key c/<index>/... in Zarr v3, or <index>.* in v2),
        files before their directories. A shard has a chunk file or two per variable (~60 for
        paper_2017): they are synced FSYNC_THREADS at a time (fsync releases the GIL, and a journalled
        file system can commit concurrent syncs together) rather than each waiting for the one before.
        On the H200's host a phase_large run's 86 fsyncs took 0.39-0.45 s in all
        (benchmarks/results/issue33_h200_fourth)."""
        files, dirs = [], []
        for k in names:
            vdir = self.zarr / k
            roots = [vdir / "c" / str(index)] + list(vdir.glob(f"{index}.*")) + [vdir / str(index)]
            for r in roots:
                if r.is_file():
                    files.append(r)
                elif r.is_dir():
                    files.extend(p for p in r.rglob("*") if p.is_file())
                    dirs.extend(sorted((p for p in r.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts)))
                    dirs.append(r)
            if (vdir / "c").is_dir():
                dirs.append(vdir / "c")
        for batch in (files, dirs):  # a directory's entry after its files' data
            if len(batch) > 1:
                with ThreadPoolExecutor(min(FSYNC_THREADS, len(batch)), thread_name_prefix="fsync") as pool:
                    list(pool.map(_fsync_path, batch))  # list(): an error is raised here
            elif batch:
                _fsync_path(batch[0])

    # ------------------------------------------------------------------ reading
    def dataset(self, plan_or_spec, tpl: xr.Dataset, partial: bool = False) -> xr.Dataset:
        """The sweep's dataset, lazy (dask-backed, one chunk per shard), in the layout of the netCDF
        export (grid dimensions for a grid spec). Refuses while shards are not done unless
        ``partial`` (then the case-stacked store as it stands). ``tpl``: as for :meth:`initialise`."""
        content, why = Manifest.read(self.manifest_path)
        if content is None:
            raise StoreError(f"{self.dir}: {why}; run `warp-tensegrity resume {self.out}`")
        spec = getattr(plan_or_spec, "spec", plan_or_spec)
        ds = xr.open_zarr(self.zarr, consolidated=False, decode_timedelta=False, chunks={})
        done = sorted(int(i) for i in content["shards"])
        if len(done) < content["n_shards"]:
            if partial:
                ds.attrs["shards_done"] = json.dumps(done)
                return ds
            raise StoreError(
                f"{content['n_shards'] - len(done)} of {content['n_shards']} shards of {self.out} are not done; "
                f"run `warp-tensegrity resume {self.out}`"
            )
        with local_dask(sync=False):  # (assemble reads the labels)
            return assemble(spec, ds, [content["shards"][str(i)]["attrs"] for i in done], tpl, self.zarr,
                            int(content["shard_size"]))


def assemble(spec, ds: xr.Dataset, shard_attrs: list[dict], tpl: xr.Dataset, zarr_path=None,
             shard_size: int = 0) -> xr.Dataset:
    """The sweep's dataset (the layout of io.shard_dataset, attributes of io.sweep_attrs) from the store,
    lazily: variable attributes from the one-column template ``tpl`` (Zarr keeps them as JSON),
    global ones from the spec and the shard records, grid dimensions for a grid spec."""
    variables = {}
    for k, v in ds.variables.items():
        v = v.copy(deep=False)
        v.encoding = {}
        if v.dtype.kind in "OUT" and not isinstance(v.dtype, np.dtypes.ObjectDType):  # labels: as _coords made them
            v = xr.Variable(v.dims, np.asarray(v.values, dtype=object), attrs=v.attrs)
        if k in tpl.variables:
            v.attrs = dict(tpl.variables[k].attrs)
        variables[k] = v
    out = xr.Dataset({k: variables[k] for k in ds.data_vars}, coords={k: variables[k] for k in ds.coords})
    last = max(str(a.get("history", "")).split(" ")[0] for a in shard_attrs)  # when the last shard was made
    layout = spec.layout()
    out.attrs = D.sweep_attrs(layout, shard_attrs, f"{last} streamed {len(shard_attrs)} shards into a Zarr store by "
                                                   "warp_tensegrity {package_version}")
    if spec.kind == "grid":
        out = _to_grid_lazy(layout, out, zarr_path, shard_size)
    elif zarr_path is not None:  # cases: the same blocks, over the one case axis
        out = _to_grid_lazy(None, out, zarr_path, shard_size)
    return out


class GridView:
    """A case-stacked Zarr array seen in grid shape (case -> grid axes, C order), for
    ``dask.array.from_array``: each block reads one contiguous run of columns (no rechunk pass,
    so an export holds one block at a time)."""

    def __init__(self, array, grid_shape: tuple):
        self.array, self.grid = array, tuple(grid_shape)
        self.shape = self.grid + tuple(array.shape[1:])
        dt = np.dtype(array.dtype)
        self.dtype = dt.newbyteorder("=") if dt.byteorder == ("<" if sys.byteorder == "little" else ">") else dt
        self.ndim = len(self.shape)

    def __getitem__(self, key):
        key = key if isinstance(key, tuple) else (key,)
        key = key + (slice(None),) * (self.ndim - len(key))
        k = len(self.grid)
        ranges = [np.arange(*sl.indices(n)) for sl, n in zip(key[:k], self.grid)]
        idx = np.ravel_multi_index(np.meshgrid(*ranges, indexing="ij"), self.grid).ravel()
        rest = key[k:]
        if idx.size and np.all(np.diff(idx) == 1):
            data = self.array[(slice(int(idx[0]), int(idx[-1]) + 1),) + rest]
        else:
            data = self.array.oindex[(idx,) + rest]
        data = np.asarray(data)
        return data.reshape(tuple(len(r) for r in ranges) + data.shape[1:])


def block_columns(ds: xr.Dataset, shard_size: int) -> dict:
    """Columns per export block for each case variable of ``ds``: a multiple of ``shard_size`` that
    holds at most one shard's bytes of all variables together (what a run kept in flight per shard).
    A variable with few bytes a column is read in few, wide blocks: the export's Dask graph has a task
    per block, and tasks for 4,000 one-shard blocks of small variables held ~20 MB (100 shards)."""
    names = _case_vars(ds)
    n = int(ds.sizes["case"])
    shard = max(int(shard_size) or n, 1)
    per = {k: max(ds[k].dtype.itemsize * int(np.prod(ds[k].shape[1:])), 1) for k in names}
    budget = shard * sum(per.values())
    return {k: min(n, shard * max(budget // (shard * per[k]), 1)) for k in names}


def grid_chunks(grid_shape: tuple, shard_size: int) -> tuple:
    """Blocks of at most shard_size columns, each a contiguous run of columns (C order)."""
    chunks, left = [], max(int(shard_size), 1)
    for n in reversed(grid_shape):
        c = min(n, left)
        chunks.append(c)
        left = max(left // n, 1) if c == n else 1
    return tuple(reversed(chunks))


def _to_grid_lazy(layout, ds: xr.Dataset, zarr_path=None, shard_size: int = 0) -> xr.Dataset:
    """io.to_grid without loading: each data variable read from the store through a GridView, in
    blocks of :func:`block_columns`. ``layout`` None: the case axis kept (a cases spec)."""
    if zarr_path is None:
        return D.to_grid(layout, ds)
    import dask.array as da
    import zarr

    group = zarr.open_group(str(zarr_path), mode="r")
    widths = block_columns(ds, shard_size)

    def split(name, v, shape):
        if name not in ds.data_vars:
            return v.data.reshape(shape + v.shape[1:])
        view = GridView(group[name], shape)
        chunks = grid_chunks(shape, widths[name]) + tuple(v.shape[1:])
        token = hashlib.sha256(f"{zarr_path}/{name}/{view.shape}/{chunks}".encode()).hexdigest()[:16]
        return da.from_array(view, chunks=chunks, name=f"wt-grid-{name}-{token}", lock=False, asarray=True,
                             meta=np.empty((0,) * view.ndim, dtype=view.dtype))

    if layout is not None:
        return D.to_grid(layout, ds, split)
    # one assign: a Dataset.__setitem__ per variable merges the whole dataset each time (39 of them took
    # 0.19 s for paper_2017)
    new = {}
    for k in widths:
        v = ds[k].variable
        new[k] = xr.Variable(v.dims, split(k, v, (v.shape[0],)), attrs=v.attrs)
    return ds.assign(new)


# ---------------------------------------------------------------------- export
def local_dask(sync: bool):
    """Dask's scheduler for this process's own reads of the store, given as its function: named by a
    string (or left to the default), dask first imports distributed to look for a client, 0.17 s on
    our CI machine and more on a GPU host's Python, in a run that has none. ``sync``: one thread (the
    export, which holds one block at a time), else dask's default threads."""
    import dask
    import dask.local
    import dask.threaded

    return dask.config.set(scheduler=dask.local.get_sync if sync else dask.threaded.get)


def export_netcdf(ds: xr.Dataset, path, whole: bool = False) -> Path:
    """Write a lazy dataset to netCDF4 atomically (:func:`warp_tensegrity.io.writing_netcdf`: a
    private temporary directory beside ``path``, fsync, os.replace), one dask chunk at a time on this
    thread, so the host holds a few chunks, never the sweep. ``whole``: the dataset is read into memory
    first and written without dask, for a sweep of one shard, whose run held as much (xarray's dask
    write imports distributed to look for a client, and builds a graph: paper_2017's export took
    0.22 s against 0.33 s on our CI machine, 0.32-0.35 s against 0.39-0.45 s on an H200 host). The file
    is the same, its netCDF chunks included. A failure is a one-line StoreError with the path, the
    errno and, for a full disk, the space the file needs; the store is kept."""
    path = Path(path)
    enc = D._encoding(ds)
    for k, v in ds.data_vars.items():
        if v.chunks and "zlib" in enc.get(k, {}):  # compressed: one netCDF chunk per dask chunk
            enc[k]["chunksizes"] = tuple(max(c) for c in v.chunks)
    import netCDF4

    # netCDF-C keeps up to 64 MiB of chunks per variable by default, and a cache of even two chunks
    # held a chunk per variable until the file closed (~6 MB of 100 shards): no cache. Each dask
    # block fills whole netCDF chunks, which HDF5 then compresses and writes at once
    cache = netCDF4.get_chunk_cache()
    netCDF4.set_chunk_cache(0, cache[1], cache[2])
    need = netcdf_bytes(ds.nbytes, max([len(c) for v in ds.data_vars.values() for c in (v.chunks or ())] or [1]))
    try:
        with D.writing_netcdf(path, need) as tmp, local_dask(sync=True):
            if whole:
                ds = ds.load()
                fault("mid-export")
                ds.to_netcdf(tmp, engine="netcdf4", format="NETCDF4", encoding=enc)
            else:
                job = ds.to_netcdf(tmp, engine="netcdf4", format="NETCDF4", encoding=enc, compute=False)
                fault("mid-export")
                job.compute()
            fault("before-replace")
    except OSError as e:
        again = f"`warp-tensegrity combine {path}` exports it again from the store, where every shard is kept"
        if is_no_space(e):
            free, where = free_bytes(path)
            raise StoreError(f"{oserror_line(e, path)}; {path.name} needs up to {fmt_bytes(need)} and "
                             f"{fmt_bytes(getattr(e, 'free', free))} is free on {where}; free space, then {again}") from None
        raise StoreError(f"{oserror_line(e, path)}; once it can be written, {again}") from None
    finally:
        netCDF4.set_chunk_cache(*cache)
    return path


# ---------------------------------------------------------------------- memory
SHARD_SHARE = 0.4
"""Share of the memory limit for the shards in flight; the rest is headroom for the writer's and the
export's buffers (Zarr codecs, the export's one block, allocator slack) and for the bookkeeping below."""
FIXED_BYTES = 6_000_000
"""Host bytes a sweep keeps whatever its shards: the plan's column batches
(:data:`~warp_tensegrity.policy.decide.ESTIMATE_CHUNK_BYTES`, 4 MB, freed but kept by the allocator),
the store's layout and the export's graph (measured 5.1 MB before the first shard, 3,100 columns)."""
RECORD_BYTES = 48_000
"""Host bytes each shard adds until the run ends: its manifest record (a checksum per variable) kept
in memory. Measured ~10 kB a shard of 39 variables since the records are appended to a journal,
~30 kB when the manifest was rewritten whole per shard; kept at the higher figure."""


def memory_need(shard_size: int, per: int, n_columns: int) -> int:
    """Host bytes a sweep of ``n_columns`` in shards of ``shard_size`` needs under a memory limit:
    the larger of its shards in flight over SHARD_SHARE and its fixed and per-shard bookkeeping over
    the rest (``per``: :func:`warp_tensegrity.policy.cost.host_bytes_per_column`)."""
    n_shards = -(-int(n_columns) // int(shard_size))
    return int(max(IN_FLIGHT * min(int(shard_size), int(n_columns)) * per / SHARD_SHARE,
                   (FIXED_BYTES + n_shards * RECORD_BYTES) / (1.0 - SHARD_SHARE)))


def limit_shard_size(shard_size: int, per: int, memory_limit: int, n_columns: int) -> int:
    """The largest shard size (at most ``shard_size``) whose sweep of ``n_columns`` fits in
    ``memory_limit`` bytes of host memory beyond the process's own (libraries, compiled kernels):
    IN_FLIGHT shards in SHARD_SHARE of it, the fixed and per-shard bookkeeping (FIXED_BYTES,
    RECORD_BYTES a shard) in the rest. Smaller shards mean more of them, so a limit can be too
    small for any shard size: refused with the least limit that works."""
    n = min(int(shard_size), int(SHARD_SHARE * memory_limit // (IN_FLIGHT * per)))
    if n >= 1 and memory_need(n, per, n_columns) <= memory_limit:
        return n
    least = min(memory_need(s, per, n_columns) for s in range(1, max(min(int(shard_size), int(n_columns)), 1) + 1))
    raise StoreError(
        f"memory limit {memory_limit / 1e6:.3g} MB is below the {least / 1e6:.3g} MB that this sweep of "
        f"{n_columns} columns needs at its best shard size ({per / 1e3:.3g} kB a column in {IN_FLIGHT} shards "
        f"in flight, plus {FIXED_BYTES / 1e6:.3g} MB and {RECORD_BYTES / 1e3:.3g} kB a shard of bookkeeping, "
        f"with headroom); raise --memory-limit or record less (run.record_strain = false)"
    )


def parse_bytes(text) -> int:
    """'64MB', '2 GiB', '1e9' -> bytes (dask's parser)."""
    from dask.utils import parse_bytes as pb

    try:
        n = int(pb(str(text)))
    except (ValueError, TypeError):
        n = 0
    if n <= 0:
        raise StoreError(f"memory limit {text!r}: give a size such as 512MB or 4GiB")
    return n


# ---------------------------------------------------------------------- pipelined writer
class ShardWriter:
    """A writer thread fed through a bounded hand-off: the caller steps shard k+1 while shard k is
    copied into the store, and at most IN_FLIGHT shards are alive on the host."""

    def __init__(self, store: SweepStore, plan, time: np.ndarray, on_done=None, in_flight: int = IN_FLIGHT):
        self.store, self.plan, self.time, self.on_done = store, plan, time, on_done
        self.slots = threading.BoundedSemaphore(in_flight)
        self.q: queue.Queue = queue.Queue()
        self.error: BaseException | None = None
        self.write_seconds = 0.0
        self.finished = threading.Event()  # set when the thread leaves _run
        self.thread = threading.Thread(target=self._run, name="warp_tensegrity-writer", daemon=True)
        self.thread.start()

    def acquire(self) -> None:
        """Wait for a free slot (a shard written); raise the writer's error if it failed."""
        self.slots.acquire()
        if self.error is not None:
            self.slots.release()
            raise self.error

    def submit(self, index: int, ds: xr.Dataset) -> None:
        self.q.put((index, ds))

    def _run(self):
        try:
            self._loop()
        finally:
            self.finished.set()

    def _loop(self):
        while True:
            item = self.q.get()
            if item is None:
                return
            index, ds = item
            del item
            try:
                if self.error is None:
                    t0 = _time.perf_counter()
                    rec = self.store.write_shard(self.plan, index, ds, self.time)
                    fault("before-mark")
                    self.store.manifest.mark_done(index, rec)
                    fault("after-mark")
                    self.write_seconds += _time.perf_counter() - t0
                    if self.on_done is not None:
                        self.on_done(index, rec)
            except BaseException as e:  # noqa: BLE001 - handed to the caller's thread
                self.error = e
            finally:
                del ds
                self.slots.release()

    def close(self) -> None:
        """Wait for every shard handed over. A signal (SIGTERM, Ctrl-C) during the wait lets the
        shard in hand finish and be marked before it is raised, so the caller never releases the
        store's lock under a write. (An Event, not Thread.join: CPython 3.11's join, interrupted,
        marks the thread stopped and a second join returns at once.)"""
        self.q.put(None)
        try:
            self.finished.wait()
        except BaseException:
            self.finished.wait()
            raise
        self.thread.join()
        if self.error is not None:
            raise self.error


def _log(msg: str, stream=None) -> None:
    print(f"warp-tensegrity: {msg}", file=stream or sys.stderr)

