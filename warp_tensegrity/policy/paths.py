"""The launch path of a batch (:func:`choose_path`): the staged kernels, the fused step (a block
per column, its constraint solve by block cyclic reduction or serially on lane 0) or the lane step
(one warp per column, :mod:`warp_tensegrity.sim.lanes.lanes`), from the settings, the device, the
batch's width and Gram band, and whether the lane step takes the batch.

Whether the lane step takes the batch: :mod:`.lane_fit`. :func:`~.decide.decide` calls
:func:`choose_path` once per run. Warp is imported only by :func:`lane_emulation`, which runs
the lane step on the CPU.
"""

from __future__ import annotations

import contextlib
import math

from ..options import RunSettings, SettingsError
from ..scene.coupling import constraint_coupling, mass_entries
from ..types import Method, Path

# fused='auto' on a GPU, where the lane step does not take the batch: the fastest measured of the
# fused step with its constraint solve by block cyclic reduction ("fused"), the fused step with
# lane 0's serial banded Cholesky ("fused-serial") and the staged kernels, per (band, precision, columns). H100, 50 prisms, RATTLE, column-steps/s
# (benchmarks/results/throughput_h100_solver.json, commit 0ac0606; tests/kernels/test_parallel_solve.py checks
# this table against it): {band: {precision: {B: (fused, fused-serial, staged)}}}; band 3 = FB, 6 = RB.
MEASURED_H100 = {
    3: {
        "fp32": {1024: (9.3e6, 6.55e6, 9.76e5), 4096: (1.19e7, 1.08e7, 3.28e6), 16384: (1.63e7, 1.45e7, 8.06e6),
                 65536: (1.71e7, 1.54e7, 2.08e7), 131072: (1.74e7, 1.45e7, 2.56e7)},
        "fp64": {1024: (3.7e6, 4.1e6, 4.81e5), 4096: (5.23e6, 4.35e6, 1.27e6), 16384: (6.59e6, 6.15e6, 3.95e6),
                 65536: (6.53e6, 6.34e6, 9.08e6), 131072: (6.51e6, 6.37e6, 8.65e6)},
    },
    6: {
        "fp32": {1024: (1.58e6, 2.26e6, 3.93e5), 4096: (1.93e6, 4.16e6, 1.14e6), 16384: (1.74e6, 4.39e6, 3.71e6),
                 65536: (1.68e6, 4.44e6, 1.02e7), 131072: (1.67e6, 4.44e6, 1.28e7)},
        "fp64": {1024: (7.07e5, 1.04e6, 1.83e5), 4096: (8.2e5, 1.6e6, 5.2e5), 16384: (8e5, 1.75e6, 1.77e6),
                 65536: (7.46e5, 1.81e6, 4.08e6), 131072: (7.38e5, 1.82e6, 4.03e6)},
    },
}
MEASURED_PATHS = (Path.FUSED, Path.FUSED_SERIAL, Path.STAGED)
# widest Gram band the fused step takes at all (its S x S blocks live in registers); wider generic
# networks run the staged kernels
FUSED_MAX_BANDWIDTH = 8


def measured_rates(bandwidth: int, precision: str, n_columns: int) -> dict:
    """{path: column-steps/s} of :data:`MEASURED_H100` for the nearest measured case: the band
    measured nearest ``bandwidth`` (3 or 6), the batch nearest ``n_columns`` in log scale."""
    band = min(MEASURED_H100, key=lambda b: (abs(b - bandwidth), b))
    rows = MEASURED_H100[band][precision]
    B = min(rows, key=lambda b: (abs(math.log2(b) - math.log2(max(n_columns, 1))), b))
    return dict(zip(MEASURED_PATHS, rows[B]))


NOT_CHECKED = "the batch was not checked for the lane step"
"""The ``lanes`` argument of :func:`choose_path` of a caller that did not check: never the lane step
(and fused = 'lanes' is refused with this reason)."""


CONTACT_PATH = "bar contact runs on the staged kernels only (sim.staged.contact; the fused and lane steps have none)"
"""Why a run with bar contact (scene contact = 'bars') takes the staged path."""


STRIKER_PATH = "the striker runs on the staged kernels only (sim.staged.striker; the fused and lane steps have none)"
"""Why a run with a striker (scene impact = 'striker') takes the staged path."""


def choose_path(settings: RunSettings, on_gpu: bool, n_columns: int, bandwidth: int = 0,
                lanes: str | None = NOT_CHECKED, contact: bool = False, striker: bool = False) -> Path:
    """The launch path. ``lanes``: why the lane step does not take the batch
    (:func:`.lane_fit.lane_support`, :func:`.lane_fit.lane_refusal`), None if it does.
    ``contact``: the batch has bar contact, which only the staged path steps (fused True or
    'lanes' are refused with :data:`CONTACT_PATH`); ``striker``: likewise a striker (:data:`STRIKER_PATH`).

    * fused 'lanes': the lane step on any device (the CPU emulates each warp with 32 fibers: slow,
      for tests), or a SettingsError that names why it does not take the batch;
    * on a GPU, RATTLE and a batch the lane step takes: the lane step for 'auto' and True. It is
      faster than the other paths at every batch measured (benchmarks/results/lanes_h200_dev/,
      FB, 50 prisms, fp32 and fp64, 1,536 and 16,384 columns);
    * otherwise fused False: staged; True: the fused variant measured faster
      (:func:`measured_rates`; the CR variant on the CPU); 'auto': RATTLE with a Gram
      half-bandwidth up to :data:`FUSED_MAX_BANDWIDTH` takes the fastest measured of the three on
      a GPU, and the CR fused step on the CPU (one lane per block there: no crossover measured).
      The lane step is never chosen on the CPU unless asked for."""
    if contact or striker:
        if settings.fused in (True, "lanes"):
            raise SettingsError(f"fused = {settings.fused!r}: {CONTACT_PATH if contact else STRIKER_PATH}; "
                                "use fused = 'auto' or false")
        return Path.STAGED
    if settings.fused == "lanes":
        if settings.method != Method.RATTLE:
            raise SettingsError(f"fused = 'lanes': the lane step is RATTLE's; needs method = 'rattle' "
                                f"(got {settings.method!r})")
        if lanes is not None:
            raise SettingsError(f"fused = 'lanes': the warp-per-column step does not take this batch: {lanes}; "
                                "use fused = 'auto', true or false")
        return Path.LANES
    if on_gpu and lanes is None and settings.method == Method.RATTLE and settings.fused in (True, "auto"):
        return Path.LANES
    if settings.fused is True:
        if bandwidth > FUSED_MAX_BANDWIDTH:
            raise SettingsError(f"fused = true: the constraint Gram band is {bandwidth} wide, above the fused "
                                f"step's {FUSED_MAX_BANDWIDTH}; use fused = 'auto' or false (staged kernels)")
        if not on_gpu:
            return Path.FUSED
        rates = measured_rates(bandwidth, settings.precision, n_columns)
        return max((Path.FUSED, Path.FUSED_SERIAL), key=rates.get)
    if settings.fused == "auto" and settings.method == Method.RATTLE and bandwidth <= FUSED_MAX_BANDWIDTH:
        if not on_gpu:
            return Path.FUSED
        rates = measured_rates(bandwidth, settings.precision, n_columns)
        return max(MEASURED_PATHS, key=rates.get)
    return Path.STAGED


@contextlib.contextmanager
def lane_emulation(path: Path, device):
    """While the lane step runs on the CPU: Warp's CPU blocks on (``wp.config.enable_cpu_blocks``:
    each emulated warp is a block of 32 fibers, which its shuffles and votes need); the previous
    setting is restored afterwards. Elsewhere (a GPU, another path): nothing."""
    if Path(path) != Path.LANES or device.is_cuda:
        yield
        return
    import warp as wp

    before = wp.config.enable_cpu_blocks
    wp.config.enable_cpu_blocks = True
    try:
        yield
    finally:
        wp.config.enable_cpu_blocks = before


def gram_bandwidth(batch) -> int:
    """Half-bandwidth of the batch's constraint Gram matrix (host-side, no kernel)."""
    return int(constraint_coupling(batch, mass_entries(batch)[0])[-1])
