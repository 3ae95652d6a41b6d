"""Model no more than a scene needs: choices taken from the requested accuracy and the scene.

* :func:`for_accuracy` maps a target relative error of the pulse measures (speed, amplitude) to
  method, precision and the fraction of the stability limit used as dt. The table is the measured
  work-precision verdict (``analysis/work_precision.md``, H100, the paper's four cases):

  ======================  =========  =========  ==============================
  accuracy wanted         method     precision  dt (fraction of the limit)
  ======================  =========  =========  ==============================
  >= 1e-2                 rattle     fp32       0.5
  [1e-3, 1e-2)            rattle     fp32       0.25 (the default)
  [1e-4, 1e-3)            rk4        fp32       0.22 (eps/1e-4)^(1/4)
  < 1e-4                  rk4        fp64       0.073 (eps/1e-5)^(1/4), at most 0.22
  ======================  =========  =========  ==============================

  fp32 pulse errors equal fp64's down to ~1e-5 (RK4: 1e-6); the final state of flexible-base
  columns after reflections is another matter (fp64 only; see the verdict).

* :func:`reachable_prisms`: prisms a disturbance can reach within ``t_end``. A chain whose
  levels couple only to their neighbours has group velocities at most ``h0 * omega_max / 2``;
  with a factor 2 for stiffening under strong compression the front covers at most
  ``omega_max * t_end`` prisms. Prisms beyond that (plus a margin) stay at rest to round-off and
  need not be simulated: the column is clamped at the last level the front can reach.
"""

from __future__ import annotations

import math

from .settings import RunSettings, SettingsError

REACH_MARGIN_PRISMS = 8


def for_accuracy(accuracy: float) -> dict:
    """Method, precision and dt_safety for a target relative error of the pulse measures."""
    if not (math.isfinite(accuracy) and 0 < accuracy < 1):
        raise SettingsError(f"accuracy = {accuracy!r} must lie in (0, 1) (relative error of pulse speed/amplitude)")
    if accuracy >= 1e-2:
        return {"method": "rattle", "precision": "fp32", "dt_safety": 0.5}
    if accuracy >= 1e-3:
        return {"method": "rattle", "precision": "fp32", "dt_safety": 0.25}
    if accuracy >= 1e-4:
        return {"method": "rk4", "precision": "fp32", "dt_safety": 0.22 * (accuracy / 1e-4) ** 0.25}
    return {"method": "rk4", "precision": "fp64", "dt_safety": min(0.22, 0.073 * (accuracy / 1e-5) ** 0.25)}


def apply_accuracy(settings: RunSettings) -> tuple[RunSettings, dict]:
    """Settings with method/precision/dt_safety chosen from ``settings.accuracy`` (if given)."""
    if settings.accuracy is None:
        return settings, {}
    if settings.dt != "auto":
        raise SettingsError(
            f"accuracy = {settings.accuracy!r} and dt = {settings.dt!r}: give one of them; accuracy chooses dt"
        )
    choice = for_accuracy(settings.accuracy)
    fields = {k: v for k, v in vars(settings).items()}
    fields.update(choice)
    return RunSettings(**fields), {"accuracy": settings.accuracy, **choice}


def reachable_prisms(omega_max: float, t_end: float, n_prisms: int) -> int:
    """Prisms from the impacted end that a disturbance can reach within t_end, plus a margin."""
    reach = math.ceil(omega_max * t_end) + REACH_MARGIN_PRISMS
    return int(min(n_prisms, max(reach, 2)))
