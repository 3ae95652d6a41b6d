"""Parameter sweeps: a TOML spec (:mod:`.spec`), planned into shards (:mod:`.plan`), each shard run
and measured (:mod:`.shard`) here or on Dask workers (:mod:`.dask`), the shard files kept and
combined (:mod:`.store`), with a progress bar (:mod:`.progress`); :mod:`.run` drives a whole sweep.
Reading and validating a spec does not import Warp."""

from .dask import local_cluster, run_shards_dask
from .plan import SweepError, SweepPlan, dry_run, plan_sweep, resolve_dt, shard_dir_for, shard_name
from .progress import ProgressBar
from .run import execute, resume_sweep, run_sweep
from .shard import compute_shard, measure_columns, run_shard
from .spec import SpecError, SweepSpec, load_spec, parse_spec
from .store import MANIFEST, SPEC_COPY, ShardCheck, check_shard, combine, load_plan_from_manifest, read_manifest, sweep_status

__all__ = [
    "MANIFEST",
    "SPEC_COPY",
    "ProgressBar",
    "ShardCheck",
    "SpecError",
    "SweepError",
    "SweepPlan",
    "SweepSpec",
    "check_shard",
    "combine",
    "compute_shard",
    "dry_run",
    "execute",
    "load_plan_from_manifest",
    "load_spec",
    "local_cluster",
    "measure_columns",
    "parse_spec",
    "plan_sweep",
    "read_manifest",
    "resolve_dt",
    "resume_sweep",
    "run_shard",
    "run_shards_dask",
    "run_sweep",
    "shard_dir_for",
    "shard_name",
    "sweep_status",
]
