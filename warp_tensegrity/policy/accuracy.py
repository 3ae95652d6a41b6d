"""The accuracy, time-step and truncation rules of a run, in plain Python (no Warp, no scene):
a spec checks ``run.accuracy`` through :func:`for_accuracy` without loading anything heavy.
:func:`~warp_tensegrity.policy.decide.decide` applies them once per run.

* :func:`for_accuracy` maps a target relative error of the pulse measures (speed, amplitude) to
  method, precision and the fraction of the stability limit used as dt. Errors accumulate as
  the pulse travels, so the rule depends on the prisms it crosses. Measured on the paper's
  50-prism column (``analysis/work_precision.md``, "Model no more than a scene needs"), the
  worse of speed and amplitude error is bounded by

      RATTLE:  0.59 (dt / dt_limit)^2 (n / 50)        RK4:  8 (dt / dt_limit)^4 (n / 50)

  with dt_limit = 2/omega_max (RATTLE) or 2*sqrt(2)/omega_max (RK4). The engine takes the
  cheaper method (force evaluations per simulated second) that meets the target, with dt at most
  half the limit, and fp32 unless the target is below 1e-4 (fp32 pulse errors equal fp64's
  down to ~1e-5). The final state of flexible-base columns after reflections is another matter:
  fp64 only (see the verdict). Flexible-base amplitudes below ~1e-4 are not promised: slack/taut
  cable switches cut RK4 to about second order there.

* :func:`reachable_prisms`: prisms a disturbance can reach within ``t_end``. A chain whose
  levels couple only to their neighbours has group velocities at most ``h0 * omega_max / 2``;
  with a factor 2 for stiffening under strong compression the front covers at most
  ``omega_max * t_end`` prisms. Prisms beyond that (plus a margin) stay at rest to round-off and
  need not be simulated: the column is clamped at the last level the front can reach.
  Not for mixed-handed columns with rigid bases: their rigid links and bars form a kinematic
  chain that moves prisms far ahead of the front (the disturbance decays only ~2x per prism
  there, against ~1000x per prism in a uniform rigid-base column), so those are never truncated.
"""

from __future__ import annotations

import math

import numpy as np

from ..options import RunSettings, SettingsError
from ..types import FORCE_EVALS, STABILITY

REACH_MARGIN_PRISMS = 8


DEFAULT_ACCURACY = 1e-3
"""Relative error of the pulse measures targeted when neither dt nor accuracy nor dt_safety is
given: the default run's dt fraction comes from the same error model as ``accuracy`` (measured on
the paper's FB and RB columns: amplitude and speed within 4.3e-4, strain history RMS within 8.5e-4
of the peak; README, benchmarks/default_accuracy.py)."""
LEGACY_DT_SAFETY = 0.25
"""dt fraction for methods without a measured error model (yoshida4, symplectic_euler)."""

ERROR_MODEL = {"rattle": (0.59, 2), "rk4": (8.0, 4)}
"""Measured error constant C and order p: error <= C (dt/dt_limit)^p (n_prisms/50)."""
REFERENCE_PRISMS = 50
MAX_FRACTION = 0.5


def for_accuracy(accuracy: float, n_prisms: int = REFERENCE_PRISMS) -> dict:
    """Method, precision and dt_safety for a target relative error of the pulse measures over a
    pulse that crosses ``n_prisms`` prisms."""
    if not (math.isfinite(accuracy) and 0 < accuracy < 1):
        raise SettingsError(f"accuracy = {accuracy!r} must lie in (0, 1) (relative error of pulse speed/amplitude)")
    best = None
    for method in ERROR_MODEL:
        frac = dt_fraction(method, accuracy, n_prisms)
        cost = FORCE_EVALS[method] / (frac * STABILITY[method])  # evaluations per unit of omega_max * t
        if best is None or cost < best[0]:
            best = (cost, method, frac)
    _, method, frac = best
    return {"method": method, "precision": "fp32" if accuracy >= 1e-4 else "fp64", "dt_safety": frac}


def dt_fraction(method: str, accuracy: float, n_prisms: int = REFERENCE_PRISMS) -> float:
    """The one accuracy -> dt decision: the fraction of the stability limit at which ``method``
    meets a relative error ``accuracy`` of the pulse measures over ``n_prisms`` prisms
    (``ERROR_MODEL``), at most ``MAX_FRACTION``."""
    C, p = ERROR_MODEL[method]
    travel = max(int(n_prisms), 1) / REFERENCE_PRISMS
    return min(MAX_FRACTION, (accuracy / (C * travel)) ** (1.0 / p))


def default_dt_safety(method: str, n_prisms: int = REFERENCE_PRISMS) -> tuple[float, float | None]:
    """(dt_safety, accuracy targeted) of a run given neither dt nor accuracy nor dt_safety."""
    if method in ERROR_MODEL:
        return dt_fraction(method, DEFAULT_ACCURACY, n_prisms), DEFAULT_ACCURACY
    return LEGACY_DT_SAFETY, None


def apply_accuracy(settings: RunSettings, n_prisms: int = REFERENCE_PRISMS) -> tuple[RunSettings, dict]:
    """Settings with method/precision/dt_safety chosen from ``settings.accuracy`` (if given) for a
    pulse crossing ``n_prisms`` prisms. Without accuracy, dt = 'auto' and no dt_safety, the dt
    fraction targets :data:`DEFAULT_ACCURACY` with the given method and precision."""
    if settings.accuracy is None:
        if settings.dt != "auto" or settings.dt_safety is not None:
            return settings, {}
        frac, target = default_dt_safety(settings.method, n_prisms)
        fields = dict(vars(settings), dt_safety=frac)
        return RunSettings(**fields), {"accuracy": target, "accuracy_source": "default", "dt_safety": frac}
    if settings.dt != "auto":
        raise SettingsError(
            f"accuracy = {settings.accuracy!r} and dt = {settings.dt!r}: give one of them; accuracy chooses dt"
        )
    choice = for_accuracy(settings.accuracy, n_prisms)
    fields = {k: v for k, v in vars(settings).items()}
    fields.update(choice)
    return RunSettings(**fields), {"accuracy": settings.accuracy, "accuracy_source": "run.accuracy", **choice}


def reachable_prisms(omega_max: float, t_end: float, n_prisms: int) -> int:
    """Prisms from the impacted end that a disturbance can reach within t_end, plus a margin."""
    reach = math.ceil(omega_max * t_end) + REACH_MARGIN_PRISMS
    return int(min(n_prisms, max(reach, 2)))

def choose_timestep(settings: RunSettings, omega_max: float):
    """Returns (dt, dt_limit, n_steps, output_every) with dt dividing the output interval."""
    limit = STABILITY[settings.method] / omega_max if omega_max > 0 else math.inf
    interval = settings.output_interval or settings.t_end / 200.0
    if settings.dt == "auto":
        safety = settings.dt_safety
        if safety is None:  # a batch run directly: the default accuracy over the reference column
            safety = default_dt_safety(settings.method)[0]
        target = safety * limit
        every = max(1, math.ceil(interval / target))
        dt = interval / every
        dt = min(dt, settings.t_end)
    else:
        dt = float(settings.dt)
        if dt > limit and not settings.allow_unstable_dt:
            raise SettingsError(
                f"dt = {dt:.4g} s exceeds the stability limit {limit:.4g} s of method {settings.method!r} "
                f"(omega_max = {omega_max:.4g} rad/s with all cables taut); use dt <= {limit:.4g}, dt = 'auto', "
                "or allow_unstable_dt"
            )
        every = max(1, round(interval / dt))
    n_steps = max(1, math.ceil(settings.t_end / dt - 1e-9))
    return dt, limit, n_steps, every


def output_times(steps: np.ndarray, dt: float) -> np.ndarray:
    """Output times [s] = step * dt, rounded to the decimals of the output interval (the step
    between outputs times dt), so printed times select exactly: 4975 * 0.002 gives 9.95, not
    9.950000000000001. Intervals with no decimal form of up to 12 decimals are not rounded."""
    steps = np.asarray(steps, dtype=np.int64)
    t = steps * dt
    if steps.size < 2:
        return t
    interval = float(steps[1] - steps[0]) * dt
    for d in range(13):
        if abs(round(interval, d) - interval) <= 1e-14 * interval:  # round-off only
            return np.round(t, d)
    return t
