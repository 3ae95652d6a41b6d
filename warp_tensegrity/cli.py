"""``warp-tensegrity`` (also ``python -m warp_tensegrity``): run sweep specs.

    warp-tensegrity run SPEC.toml -o OUT.nc [--device cpu|cuda:N] [--dry-run] [--dask N | --scheduler ADDR]
    warp-tensegrity resume OUT.nc            (or: resume SPEC.toml -o OUT.nc) [--overwrite]
    warp-tensegrity status OUT.nc
    warp-tensegrity combine OUT.nc
    warp-tensegrity plot OUT.nc KIND [-o FIG.png]      (phase, spacetime, profile, work-precision)
    warp-tensegrity --version
    warp-tensegrity lens SPEC.toml -o OUT.nc [--device cpu|cuda:N] [--dry-run] [--time-limit S] [--overwrite]  (docs/lens.md)
    warp-tensegrity validate [-o FIGDIR] [--only NAME ...]   (closed-form gallery, docs/validation.md)
    warp-tensegrity init [--example paper|phase|lens] [-o SPEC.toml]  (a commented starting spec)

Messages go through :mod:`logging` on stderr (``-v``: debug and Warp's own start-up lines,
``-q``: warnings only, no progress bar); command results (status, dry run) go to stdout.
Warp is imported only when a command needs the engine, so ``--help`` is instant. Ctrl-C and
SIGTERM unwind a command alike (finished shards kept, lock released; exit 130 and 143); an
OSError that no command words itself ends as one line with its errno and path.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
from pathlib import Path

from . import plot
from .cli_args import add_device, add_estimate_options, file_name, positive_int
from .init_spec import add_init_parser, run_init
from .lens.command import add_lens_parser, run_lens_command
from .measure.nan_reasons import all_failed, dataset_summary
from .options import OptionError
from .outputs import OutputError, oserror_text
from .overrides import parse_set
from .plot import KINDS, PlotError
from .policy.calibrate import estimate_plan
from .policy.cost import DEFAULT_TIME_LIMIT
from .provenance import version_text
from .runtime import WarpSetupError, init_warp, warp_facts
from .scene.network import NetworkError
from .validation import report, run_validation
from .validation.closed_forms import long_wave_speeds
from .validation.figures import write_figures

log = logging.getLogger("warp_tensegrity")

EXIT_OK, EXIT_ERROR, EXIT_INCOMPLETE, EXIT_ALL_FAILED = 0, 1, 3, 4
EXIT_INTERRUPTED, EXIT_TERMINATED = 128 + signal.SIGINT, 128 + signal.SIGTERM  # 130, 143: as a shell reports them
EXIT_TEXT = ("Exit status: 0 done (a run also when some cases failed or have NaN measures: its summary lines say "
             "why); 1 error; 3 status: cases remain; 4 run, resume: every case failed (the line says the likely "
             "cause); 130 interrupted (Ctrl-C); 143 terminated (SIGTERM).")


def _add_exec_options(p: argparse.ArgumentParser, dry_run: bool = True):
    add_device(p)
    p.add_argument("--shard-size", type=positive_int, default=None, metavar="N",
                   help="columns per shard (default: the spec's run.shard_size)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--dask", type=positive_int, default=None, metavar="N",
                   help="run shards on a local Dask cluster of N worker processes (one per GPU, or N CPU workers)")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run shards on an existing Dask cluster (e.g. tcp://host:8786)")
    p.add_argument("--memory-limit", default=None, metavar="SIZE",
                   help="host memory the sweep may add, e.g. 512MB (lowers the shard size to fit; refused if none fits)")
    add_estimate_options(p, "the run plan (columns, shards, dt, steps, path) and the estimated memory and time"
                         if dry_run else "")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (it shows only when stderr is a terminal anyway)")
    p.add_argument("--keep-store", action=argparse.BooleanOptionalAction, default=True,
                   help="keep the Zarr store OUT.nc.sweep/ (about the output's size) after OUT.nc is written, "
                        "for `combine` and `resume` (default); --no-keep-store removes it")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="warp-tensegrity",
        description="GPU batched parameter sweeps of impact waves in tensegrity columns (NVIDIA Warp).",
        epilog=f"Spec reference and dataset layout: docs/sweeps.md. {EXIT_TEXT}",
    )
    parser.add_argument("--version", action="store_true",
                        help="print the package version, commit, Warp version and default device, then exit")
    verbosity = parser.add_mutually_exclusive_group()
    verbosity.add_argument("-v", "--verbose", action="count", default=0,
                           help="more messages: debug logging and Warp's start-up lines")
    verbosity.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only; no progress bar")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    common = _verbosity_parent()

    p = sub.add_parser("run", parents=[common], help="run a sweep spec into a netCDF file",
                       description="Run SPEC: shards stream into the Zarr store OUT.sweep/ as they finish; "
                                   "OUT is exported from it (netCDF).")
    p.add_argument("spec", type=file_name, metavar="SPEC", help="sweep spec (TOML)")
    p.add_argument("-o", "--output", type=file_name, required=True, metavar="OUT.nc",
                   help="netCDF output (the store goes to OUT.nc.sweep/)")
    p.add_argument("--overwrite", action="store_true", help="discard an earlier run's store and output")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", dest="overrides",
                   help="override one spec option, typed and checked like the file (e.g. --set run.t_end=2.0, "
                        "--set scene.n_prisms=8); repeatable; every option: docs/sweeps.md")
    _add_exec_options(p)

    p = sub.add_parser("resume", parents=[common], help="finish an interrupted run",
                       description="Reuse the shards that check out (same spec, code and columns), "
                                   "recompute the others, combine. Give OUT.nc, or SPEC -o OUT.nc.")
    p.add_argument("target", type=file_name, metavar="OUT.nc|SPEC", help="the run's output (or its spec, with -o)")
    p.add_argument("-o", "--output", type=file_name, default=None, metavar="OUT.nc", help="output, when TARGET is a spec")
    p.add_argument("--overwrite", action="store_true",
                   help="discard finished work of another run (a store made for another spec, code or shard size, "
                        "or an output that is not this run's) instead of refusing")
    _add_exec_options(p)

    p = sub.add_parser("status", parents=[common], help="cases done, diverged and remaining")
    p.add_argument("output", type=file_name, metavar="OUT.nc")
    p.add_argument("--json", action="store_true", help="machine-readable output")

    p = sub.add_parser("combine", parents=[common], help="export a finished run's store to OUT.nc again")
    p.add_argument("output", type=file_name, metavar="OUT.nc")

    p = sub.add_parser("plot", parents=[common], help="plot a sweep's dataset (warp_tensegrity.plot)",
                       description="Draw one figure of OUT.nc with warp_tensegrity.plot and save it.")
    p.add_argument("dataset", type=file_name, metavar="OUT.nc", help="a sweep's netCDF output (or a work-precision study's)")
    p.add_argument("kind", choices=sorted(KINDS), help="; ".join(f"{k}: {v}" for k, v in sorted(KINDS.items())))
    p.add_argument("-o", "--output", default=None, metavar="FIG.png",
                   help="figure file (default: OUT-KIND.png beside the dataset)")
    p.add_argument("--var", default="speed", help="phase: the measured variable to map (default speed)")
    p.add_argument("--x", default=None, help="phase: parameter on the x axis (default: the first swept)")
    p.add_argument("--y", default=None, help="phase: parameter on the y axis (default: the second swept)")
    p.add_argument("--sel", action="append", default=[], metavar="NAME=VALUE",
                   help="pick one value of a dimension (nearest), e.g. --sel base_rigidity=1 --sel case=3")
    p.add_argument("--times", default=None, metavar="T1,T2,...", help="profile: output times [s]")
    add_lens_parser(sub, parents=[common])  # `lens SPEC -o OUT.nc`: the lens package owns it
    add_init_parser(sub, parents=[common])  # `init [--example ...]`: a commented starting spec
    _add_validate_parser(sub, common)
    return parser


def _add_validate_parser(sub, common) -> None:
    p = sub.add_parser("validate", parents=[common], help="check the engine against closed forms (docs/validation.md)",
                       description="Run the validation gallery (fp64): the Bessel impact, the sonic-vacuum "
                                   "solitary wave, the Bloch dispersion, the FB modal sum, the interface, the diatomic gap, a "
                                   "striker on the linear chain and the end preload; print every number against its tolerance; exit 1 if one fails.")
    p.add_argument("-o", "--output", default=None, metavar="FIGDIR", help="write one figure per check into FIGDIR")
    p.add_argument("--only", nargs="+", default=None, metavar="NAME",
                   help="run these checks only: bessel, soliton, dispersion, fb_modal, interface, diatomic, striker, preload")
    add_device(p, "cpu", "cpu")


def _validate(args) -> int:
    init_warp(verbose=bool(args.verbose))
    try:
        groups = run_validation(args.only, device=None if args.device == "auto" else args.device)
    except ValueError as e:
        log.error("error: %s", e)
        return EXIT_ERROR
    print(report(groups))
    if args.output:
        for path in write_figures(groups, args.output):
            log.info("wrote %s", path)
    return EXIT_OK if all(g.passed for g in groups) else EXIT_ERROR


def _verbosity_parent() -> argparse.ArgumentParser:
    """-v/-q after the subcommand too (``run -q ...``); SUPPRESS keeps the top-level value when
    the subcommand does not give its own."""
    common = argparse.ArgumentParser(add_help=False)
    g = common.add_mutually_exclusive_group()
    g.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                   help="more messages: debug logging and Warp's start-up lines")
    g.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                   help="warnings and errors only; no progress bar")
    return common


def _report_status(st: dict, as_json: bool) -> str:
    if as_json:
        return json.dumps(st, indent=2)
    lines = [
        f"output:     {st['output']}{' (combined, up to date)' if st['combined'] else ''}",
        f"spec:       {st['spec']}",
        f"columns:    {st['columns']} in {st['shards']} shards of {st['shard_size']}",
        f"done:       {st['cases_done']} cases ({st['shards_done']} shards)",
        f"diverged:   {st['cases_diverged']} cases",
        f"remaining:  {st['cases_remaining']} cases",
    ]
    if st["shards_stale"]:
        lines.append("stale:      " + "; ".join(f"shard {i}: {r}" for i, r in st["shards_stale"][:5]))
    if st["shards_corrupt"]:
        lines.append("corrupt:    " + "; ".join(f"shard {i}: {r}" for i, r in st["shards_corrupt"][:5]))
    return "\n".join(lines)


class _StderrHandler(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is at the time (pytest's capture swaps it between calls)."""

    def __init__(self):
        super().__init__()
        self.setFormatter(logging.Formatter("warp-tensegrity: %(message)s"))

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):  # logging.StreamHandler.__init__ assigns it
        pass


def setup_logging(verbose: int = 0, quiet: bool = False) -> None:
    """One stderr handler on the package logger: INFO by default, DEBUG with -v, WARNING with -q."""
    log.setLevel(logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO)
    if not any(isinstance(h, _StderrHandler) for h in log.handlers):
        log.addHandler(_StderrHandler())
    log.propagate = False


def _looks_like_spec(path: str) -> bool:
    return path.endswith(".toml")


class Terminated(KeyboardInterrupt):
    """SIGTERM (what batch schedulers send before SIGKILL), raised in the main thread where Ctrl-C's
    KeyboardInterrupt would be: the same unwinding keeps the finished shards and releases the lock."""


def _on_sigterm(signum, frame):
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second one must not cut the unwinding short
    raise Terminated()


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    setup_logging(args.verbose, args.quiet)
    if args.command is None and not args.version:
        parser.error("give a COMMAND (run, resume, status, combine, plot, lens, init, validate) or --version")
    on_main = threading.current_thread() is threading.main_thread()  # signal handlers: the main thread only
    previous = signal.signal(signal.SIGTERM, _on_sigterm) if on_main else None
    try:
        return _main(args)
    finally:
        if on_main:
            signal.signal(signal.SIGTERM, previous)


def _main(args) -> int:
    try:
        if args.version:
            init_warp(verbose=bool(args.verbose), kernels=False)  # no kernels: a read-only HOME is fine
            print(version_text(warp_facts()))
            return EXIT_OK
        from .sweep.errors import SweepError  # the sweep package imports xarray: not at `--help`

        try:
            return _dispatch(args)
        except (OptionError, NetworkError, SweepError, PlotError, WarpSetupError, OutputError) as e:  # SpecError,
            log.error("error: %s", e)                     # SettingsError: OptionError; BudgetError: SweepError
            return EXIT_ERROR
    except KeyboardInterrupt as e:
        how = "terminated (SIGTERM)" if isinstance(e, Terminated) else "interrupted"
        if args.command in ("run", "resume"):
            log.warning("%s; finished shards are kept: `warp-tensegrity resume %s` continues", how,
                        args.output or args.target)
        else:
            log.warning("%s", how)
        return EXIT_TERMINATED if isinstance(e, Terminated) else EXIT_INTERRUPTED
    except OSError as e:  # the last resort: whatever the commands did not word themselves, in one line
        log.error("error: %s", oserror_text(e))
        return EXIT_ERROR


def _dispatch(args) -> int:
    if args.command == "validate":
        return _validate(args)
    if args.command == "init":
        return run_init(args)
    if args.command == "lens":
        init_warp(verbose=bool(args.verbose))
        return run_lens_command(args)
    from .sweep import plan as sweep_plan  # the sweep package imports xarray: not at `--help`
    from .sweep import run as sweep  # imports xarray: not at `--help`
    from .sweep.errors import SweepError  # imports xarray: not at `--help`
    from .sweep.spec import load_spec  # imports xarray: not at `--help`
    from .sweep.status import recorded_header  # imports xarray: not at `--help`

    if args.command in ("run", "resume"):
        init_warp(verbose=bool(args.verbose))
        device = None if args.device == "auto" else args.device
        if args.command == "run":
            spec = load_spec(Path(args.spec), overrides=parse_set(args.overrides))
            out = Path(args.output)
            if not args.dry_run:  # a directory, an earlier run, an unwritable place: refused before any probe
                sweep.check_output(out, overwrite=args.overwrite)
            plan = sweep_plan.plan_sweep(spec, out, device=device, shard_size=args.shard_size,
                                         memory_limit=args.memory_limit)
        else:
            if _looks_like_spec(args.target):
                if not args.output:
                    raise SweepError("resume SPEC needs -o OUT.nc")
                out = Path(args.output)
                if not args.dry_run:
                    sweep.check_output(out, resume=True)
                recorded = recorded_header(out).get("shard_size")  # the run's, as `resume OUT.nc` takes it
                plan = sweep_plan.plan_sweep(load_spec(Path(args.target)), out, device=device,
                                             shard_size=args.shard_size or recorded, memory_limit=args.memory_limit)
            else:
                out = Path(args.target)
                if args.output and Path(args.output) != out:
                    raise SweepError("give either resume OUT.nc or resume SPEC -o OUT.nc")
                plan = sweep.load_plan_from_manifest(out, device=device, shard_size=args.shard_size,
                                                     memory_limit=args.memory_limit)
        from .sweep import budget  # imports xarray: not at `--help`
        from .sweep.status import shards_to_run  # imports xarray: not at `--help`

        limits = {"time_limit": args.time_limit or DEFAULT_TIME_LIMIT}
        cost = None
        if args.dry_run or not args.ignore_estimate:
            todo = shards_to_run(plan) if args.command == "resume" else None  # a resume prices what is left
            cost = estimate_plan(plan, recalibrate=args.recalibrate, shards=todo)  # the one estimate: dry run and limits
        if args.dry_run:
            print(sweep_plan.dry_run(plan, cost))
            found = budget.hard_problems(plan) + budget.problems(plan, cost, **limits)
            print("fits:        " + ("yes (memory, disk, time limit)" if not found else "NO: " + "; ".join(found)))
            if args.command == "resume" and plan.shard_dir.exists():
                st = sweep.sweep_status(out, plan.spec)
                print(f"resume:      {st['cases_done']} columns done, {st['cases_remaining']} to run")
            return 0
        budget.check_run(plan, cost, ignore=args.ignore_estimate, **limits)
        before = _mtime(out)
        path = sweep.execute(
            plan,
            resume=args.command == "resume",
            overwrite=getattr(args, "overwrite", False),
            progress=False if (args.no_progress or args.quiet) else None,  # None: on a terminal only
            dask_workers=args.dask,
            scheduler=args.scheduler,
            keep_store=args.keep_store,
            cost=cost,
        )
        if _mtime(path) != before:  # a resume of a finished, exported run writes nothing
            log.info("wrote %s", path)
        return _log_nan_summary(path)
    if args.command in ("status", "combine"):  # Warp's device facts, no kernels: a read-only HOME is fine
        init_warp(verbose=bool(args.verbose), kernels=False)
    if args.command == "status":
        st = sweep.sweep_status(args.output)
        print(_report_status(st, args.json))
        return 0 if st["cases_remaining"] == 0 else EXIT_INCOMPLETE
    if args.command == "combine":
        path = sweep.combine(args.output)
        log.info("wrote %s", path)
        return 0
    if args.command == "plot":
        return _plot(args)
    raise AssertionError(args.command)  # pragma: no cover


def _plot(args) -> int:
    sel = {}
    for item in args.sel:
        name, sep, value = item.partition("=")
        if not sep:
            raise PlotError(f"--sel {item!r}: give NAME=VALUE")
        try:
            sel[name] = float(value)
        except ValueError:
            sel[name] = value
    times = None
    if args.times:
        try:
            times = [float(t) for t in args.times.split(",")]
        except ValueError:
            raise PlotError(f"--times {args.times!r}: give comma-separated seconds") from None
    out = Path(args.output) if args.output else Path(args.dataset).with_name(f"{Path(args.dataset).stem}-{args.kind}.png")
    plot.plot_file(args.dataset, args.kind, var=args.var, x=args.x, y=args.y, sel=sel, times=times, output=out)
    log.info("wrote %s", out)
    return 0


def _mtime(path) -> int | None:
    try:
        return Path(path).stat().st_mtime_ns
    except OSError:
        return None


def _log_nan_summary(path) -> int:
    """One line per kind of NaN measurement in the output (warp_tensegrity.measure.nan_reasons), or
    when every case failed one error line with the likely cause, and EXIT_ALL_FAILED."""
    from .io import open_sweep  # imports xarray: not at `--help`
    from .measure.feasibility import dataset_summary as feasibility_summary

    with open_sweep(path, load=False) as ds:  # reads the per-case flags it looks at, not the records
        failed = all_failed(ds, long_wave_speeds)
        if failed:  # one line, in place of the per-kind ones
            log.error("error: %s", failed)
            return EXIT_ALL_FAILED
        for line in dataset_summary(ds) + feasibility_summary(ds):
            log.info("%s", line)
    return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
