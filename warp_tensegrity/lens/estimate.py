"""The lens job's cost before it runs, from the one cost model (:mod:`warp_tensegrity.policy.cost`):
its two batches decided as they will run (:func:`~warp_tensegrity.policy.decide.decide`) and priced
from one calibration probe of the first. The calibration batch runs ``calibration.count`` columns
to ``run.t_end``; the verification batch the designed and uniform arrays of every focal point
(2 x foci x array columns) to at least ``run.t_end`` (its end waits on the designed exit times),
so its figure is a lower bound. ``warp-tensegrity lens --dry-run`` prints it and ``--time-limit``
holds the run to it, as for sweeps."""

from __future__ import annotations

import numpy as np

from ..policy.calibrate import probe, reference_state_count
from ..options import SettingsError
from ..policy.cost import fmt_seconds, predict
from ..policy.decide import decide
from ..scene.batch import column_params
from . import host as H
from .spec import LensSpec, LensSpecError, lens_settings


def estimate_lens(spec: LensSpec, device: str | None = None, recalibrate: bool = False) -> dict:
    """{"seconds", "stages_s" (both batches), "batches": {name: (columns, steps, seconds)}, "device", "probe"}."""
    cfg, c = spec.column.config(), spec.calibration
    common = {"v0": spec.incident.v0, "base_rigidity": spec.column.base_rigidity}
    n_ver = 2 * len(spec.design.focal_points) * len(H.column_positions(spec.array.layout, spec.array.shape,
                                                                        spec.array.spacing))
    cal_params = column_params(cfg, {"prestrain": np.linspace(c.prestrain_min, c.prestrain_max, c.count), **common})
    # the designed prestrains lie in the calibrated range; the verification steps with the calibration's dt
    ver_params = column_params(cfg, {"prestrain": np.linspace(c.prestrain_min, c.prestrain_max, n_ver), **common})
    cal_run = _decide(cfg, cal_params, lens_settings(spec, device), "calibration")
    ver_run = _decide(cfg, ver_params, lens_settings(spec, device, dt=cal_run.dt), "verification")
    B = int(cal_params["prestrain"].size)
    cal = probe(cfg, cal_params, cal_run, B, use_cache=not recalibrate)  # one probe: the same step in both
    out, total = {}, {}
    for name, params, run in (("calibration", cal_params, cal_run), ("verification", ver_params, ver_run)):
        B, states = int(params["prestrain"].size), reference_state_count(params)
        st = dict(predict(cal, run, [B], True, shard_states=[states], planned=(B, states))["stages_s"])
        if total:  # imports and kernel loads are paid once
            st["import"] = st["compile"] = 0.0
        total = {k: total.get(k, 0.0) + v for k, v in st.items()}
        out[name] = (B, run.n_steps, sum(st.values()))
    return {"seconds": float(sum(total.values())), "stages_s": total, "batches": out, "device": cal["device_label"],
            "probe": cal}


def _decide(cfg, params, settings, name: str):
    """The batch's run plan; a LensSpecError naming the batch where decide refuses its sizes (more
    steps than the device's counter holds, or a column's records beyond the machine's memory:
    :func:`~warp_tensegrity.policy.cost.size_problems`), before anything of that size is built."""
    try:
        return decide(cfg, params, settings)
    except SettingsError as e:
        raise LensSpecError(f"the {name} batch: {e}") from None


def describe(est: dict) -> str:
    """The dry run's lines."""
    lines = [f"device:      {est['device']}"]
    for name, (B, steps, secs) in est["batches"].items():
        lines.append(f"{name + ':':<13} {B:,} columns x {steps:,} steps, ~{fmt_seconds(secs)}"
                     + (" (at least: it ends when the designed exit times are past)" if name == "verification" else ""))
    lines.append(f"time:        ~{fmt_seconds(est['seconds'])} wall ("
                 + ", ".join(f"{k} {v:.3g} s" for k, v in est["stages_s"].items()) + ")")
    p = est["probe"]
    lines.append(f"probe:       {p['probe_columns']} columns x {p['probe_steps']} steps on this device "
                 f"({p['column_step_seconds']:.3g} s per column-step; cached {p['created']}; --recalibrate renews it)")
    return "\n".join(lines)
