"""``warp-tensegrity lens SPEC -o OUT.nc``: calibrate, design, verify, write the CF netCDF."""

from __future__ import annotations

import sys
from pathlib import Path

from ..options import SettingsError
from ..scene.network import NetworkError
from .spec import LensSpecError, load_lens_spec


def add_lens_parser(sub, parents=()) -> None:
    p = sub.add_parser("lens", parents=list(parents), help="design and verify a tunable-focus acoustic lens (docs/lens.md)",
                       description="Calibrate T(p), A(p), W(p) in one batch, design the prestrains for each "
                                   "focal point, verify the array in one batch, write OUT.nc.")
    p.add_argument("spec", metavar="SPEC", help="lens spec (TOML), e.g. sweeps/lens_ci.toml")
    p.add_argument("-o", "--output", required=True, metavar="OUT.nc", help="netCDF output")
    p.add_argument("--device", default=None, help="Warp device: cpu or cuda:N (default: the spec's run.device, else the GPU if there is one)")


def run_lens_command(args) -> int:
    from .design import CalibrationError  # imports SciPy: not at `--help`

    log = (lambda *a: None) if getattr(args, "quiet", False) else (lambda msg: print(msg, file=sys.stderr))
    try:
        spec = load_lens_spec(args.spec)
        from .io import write_lens  # imports xarray: not at `--help`
        from .run import run_lens  # imports SciPy and xarray: not at `--help`

        ds = run_lens(spec, device=args.device, log=log)
        path = write_lens(ds, Path(args.output))
    except (LensSpecError, CalibrationError, SettingsError, NetworkError) as e:
        print(f"warp-tensegrity lens: error: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        print(f"warp-tensegrity lens: error: cannot write {args.output!r}: {e}", file=sys.stderr)
        return 1
    print(f"wrote {path}")
    return 0
