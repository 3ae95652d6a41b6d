"""Parameter sweeps: a TOML spec (:mod:`.spec`), planned into shards (:mod:`.plan`), each shard run
and measured (:mod:`.shard`) here or on Dask workers (:mod:`.dask`), the shard files kept and
combined (:mod:`.store`), with a progress bar (:mod:`.progress`); :mod:`.run` drives a whole sweep.
Reading and validating a spec does not import Warp."""

from .dask import local_cluster, run_shards_dask
from .errors import SpecError, SweepError
from .plan import SweepPlan, dry_run, plan_sweep, resolve_dt
from .progress import ProgressBar
from .run import combine, execute, load_plan_from_manifest, resume_sweep, run_sweep, sweep_status
from .shard import compute_shard, measure_columns, run_and_check, run_shard
from .spec import SweepSpec, load_spec, parse_spec
from .store import MANIFEST, SPEC_COPY, ShardCheck, check_shard, read_manifest, shard_dir_for, shard_name

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
    "run_and_check",
    "run_shard",
    "run_shards_dask",
    "run_sweep",
    "shard_dir_for",
    "shard_name",
    "sweep_status",
]
