"""``warp-tensegrity lens SPEC -o OUT.nc``: calibrate, design, verify, write the CF netCDF."""

from __future__ import annotations

import sys
from pathlib import Path

from ..options import SettingsError
from ..scene.network import NetworkError
from ..cli_args import add_device, add_estimate_options
from ..outputs import OutputError, check_output_file, oserror_text
from ..policy.cost import DEFAULT_TIME_LIMIT, fmt_seconds
from .spec import LensSpecError, load_lens_spec


def add_lens_parser(sub, parents=()) -> None:
    p = sub.add_parser("lens", parents=list(parents), help="design and verify a tunable-focus acoustic lens (docs/lens.md)",
                       description="Calibrate T(p), A(p), W(p) in one batch, design the prestrains for each "
                                   "focal point, verify the array in one batch, write OUT.nc.")
    p.add_argument("spec", metavar="SPEC", help="lens spec (TOML), e.g. sweeps/lens_ci.toml")
    p.add_argument("-o", "--output", required=True, metavar="OUT.nc", help="netCDF output")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    add_device(p)
    add_estimate_options(p, "the two batches and the estimated time")


def run_lens_command(args) -> int:
    from .design import CalibrationError  # imports SciPy: not at `--help`

    log = (lambda *a: None) if getattr(args, "quiet", False) else (lambda msg: print(msg, file=sys.stderr))
    try:
        spec = load_lens_spec(args.spec)
        from .run import check_memory, run_lens  # imports SciPy and xarray: not at `--help`

        if not args.dry_run:  # an existing output, a directory, an unwritable place: before any batch
            check_output_file(args.output, exists_ok=args.overwrite)
        check_memory(spec)  # before anything is built: a record that cannot fit is refused with its figures
        if args.dry_run or not args.ignore_estimate:
            from .estimate import describe, estimate_lens  # imports xarray (sweep.budget): not at `--help`

            est = estimate_lens(spec, device=args.device, recalibrate=args.recalibrate)
            limit = DEFAULT_TIME_LIMIT if args.time_limit is None else args.time_limit
            if args.dry_run:
                print(describe(est))
                print("fits:        " + ("yes (time limit)" if est["seconds"] <= limit else "NO: over the time limit"))
                return 0
            if est["seconds"] > limit:
                print(f"warp-tensegrity lens: error: the estimate is {fmt_seconds(est['seconds'])} and the time limit is "
                      f"{fmt_seconds(limit)} (--time-limit SECONDS; --ignore-estimate runs it anyway)", file=sys.stderr)
                return 1
        from .io import write_lens  # imports xarray: not at `--help`

        ds = run_lens(spec, device=args.device, log=log)
        path = write_lens(ds, Path(args.output))
    except (LensSpecError, CalibrationError, SettingsError, NetworkError, OutputError) as e:
        print(f"warp-tensegrity lens: error: {e}", file=sys.stderr)
        return 1
    except OSError as e:  # after the output's check (a full disk, a race): the errno and the path
        print(f"warp-tensegrity lens: error: cannot write {args.output}: {oserror_text(e)}", file=sys.stderr)
        return 1
    print(f"wrote {path}")
    return 0
