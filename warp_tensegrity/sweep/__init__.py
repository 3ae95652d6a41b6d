"""Parameter sweeps: a TOML spec (:mod:`.spec`, its tables checked by :mod:`.parse`), planned into
shards (:mod:`.plan`), each shard run and measured (:mod:`.shard`) here or on Dask workers
(:mod:`.dask`), streamed into one Zarr store and exported to netCDF (:mod:`.store`; its manifest,
checksums and lock in :mod:`.manifest`), with a progress bar (:mod:`.progress`); :mod:`.run`
drives a whole sweep, :mod:`.status` reports on one.
Reading and validating a spec does not import Warp."""

from .dask import local_cluster, run_shards_dask
from .errors import SpecError, SweepError
from .manifest import MANIFEST, SPEC_COPY, SweepLock, shard_dir_for
from .plan import SweepPlan, decide_sweep, dry_run, plan_sweep
from .progress import ProgressBar
from .run import combine, execute, load_plan_from_manifest, open_sweep, resume_sweep, run_sweep, sweep_status
from .shard import compute_and_write, compute_shard, measure_columns, template_dataset
from .spec import SweepSpec, load_spec, parse_spec
from .store import SweepStore

__all__ = [
    "MANIFEST",
    "SPEC_COPY",
    "ProgressBar",
    "SpecError",
    "SweepError",
    "SweepLock",
    "SweepPlan",
    "SweepSpec",
    "SweepStore",
    "combine",
    "compute_and_write",
    "compute_shard",
    "decide_sweep",
    "dry_run",
    "execute",
    "load_plan_from_manifest",
    "load_spec",
    "local_cluster",
    "measure_columns",
    "open_sweep",
    "parse_spec",
    "plan_sweep",
    "resume_sweep",
    "run_shards_dask",
    "run_sweep",
    "shard_dir_for",
    "sweep_status",
    "template_dataset",
]
