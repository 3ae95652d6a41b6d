"""Scale a sweep out with Dask distributed: shards are tasks, one worker per GPU (or N CPU workers).

Each task runs one shard on its worker and writes the shard file atomically (a temporary file in
the shard directory, then os.replace), returning the path; the client combines the shard files
with xarray exactly as a single-process run does, so both give the same dataset.

* ``n_workers=N``: a LocalCluster of N single-threaded worker processes. With device None
  (auto) and GPUs present, worker k uses ``cuda:(k % n_gpus)``; with ``device="cpu"`` all
  workers run on the CPU.
* ``scheduler=ADDRESS``: an existing cluster (e.g. ``dask-scheduler`` plus one
  ``dask-worker --nthreads 1`` per GPU started with CUDA_VISIBLE_DEVICES set). The shard
  directory must be on a file system every worker can write to.
"""

from __future__ import annotations

from pathlib import Path

from ..provenance import code_version


def _gpu_count() -> int:
    _quiet_warp()
    try:
        import warp as wp

        wp.init()
        return int(wp.get_cuda_device_count())
    except Exception:
        return 0


def _quiet_warp() -> None:
    try:
        import warp

        if hasattr(warp.config, "log_level") and hasattr(warp, "LOG_WARNING"):
            warp.config.log_level = warp.LOG_WARNING
    except ImportError:  # pragma: no cover
        pass


def _shard_task(run_one, plan, index: int, device_map: dict | None, quiet: bool = True):
    """Runs on a worker: ``run_one(plan, index, device)`` (compute shard ``index``, write it
    atomically, check it) on this worker's device; returns what it returns."""
    if quiet:
        _quiet_warp()

    here = code_version()
    if here != plan.code_version:
        raise RuntimeError(
            f"worker code version {here} differs from the client's {plan.code_version}; "
            f"install the same warp_tensegrity sources on every worker"
        )
    device = None
    if device_map:
        try:
            from distributed import get_worker

            device = device_map.get(get_worker().address)
        except Exception:
            device = None
    return run_one(plan, index, device)


def _device_map(client, device: str | None) -> dict:
    """worker address -> device for a local cluster (None: let each worker pick)."""
    workers = sorted(client.scheduler_info()["workers"])
    if device is not None:
        return {w: device for w in workers}
    n_gpu = client.submit(_gpu_count, pure=False).result()
    if n_gpu <= 0:
        return {w: "cpu" for w in workers}
    return {w: f"cuda:{k % n_gpu}" for k, w in enumerate(workers)}


def local_cluster(n_workers: int, **kwargs):
    """A LocalCluster of ``n_workers`` single-threaded worker processes (HTTP/dashboard on a free port)."""
    from distributed import LocalCluster

    opts = dict(n_workers=int(n_workers), threads_per_worker=1, processes=True, dashboard_address=":0")
    opts.update(kwargs)
    return LocalCluster(**opts)


def run_shards_dask(plan, indices, run_one, *, n_workers: int | None = None, scheduler: str | None = None, client=None,
                    bar=None) -> list[Path]:
    """Run shards ``indices`` of ``plan`` as Dask tasks, each ``run_one(plan, index, device)``
    (:func:`~warp_tensegrity.sweep.shard.run_and_check`); returns the shard paths (in ``indices`` order)."""
    from distributed import Client, as_completed

    cluster = None
    own_client = client is None
    if client is None:
        if scheduler:
            client = Client(scheduler)
        else:
            if not n_workers or n_workers < 1:
                raise ValueError("give n_workers >= 1, a scheduler address or a client")
            cluster = local_cluster(n_workers)
            client = Client(cluster)
    try:
        # Local workers get a device each; on an external cluster each worker picks its own
        # (device None = its GPU) unless a device was asked for.
        if cluster is not None:
            dmap = _device_map(client, plan.device)
        elif plan.device is not None:
            dmap = {w: plan.device for w in client.scheduler_info()["workers"]}
        else:
            dmap = None
        futures = client.map(_shard_task, [run_one] * len(indices), [plan] * len(indices), list(indices), [dmap] * len(indices),
                             pure=False, retries=0)
        paths = {}
        done_cols = bar.done if bar is not None else 0
        failed = bar.diverged if bar is not None else 0
        for fut in as_completed(futures):
            index, path, n_failed = fut.result()
            a, b = plan.shards[index]
            paths[index] = Path(path)
            done_cols += b - a
            failed += n_failed
            if bar is not None:
                bar.update(done_cols, failed, force=True)
        return [paths[i] for i in indices]
    finally:
        if own_client:
            client.close()
        if cluster is not None:
            cluster.close()
