"""The validation checks: the engine (fp64, CPU by default) against closed forms.

Each ``check_*`` function runs small scenes of the paper's prism (:class:`ColumnConfig` defaults:
a = 5 mm, h0 = 6.2 mm, EA = 0.337 N, m = 0.0249 kg; massless bars, masses on the bases, the
half-mass end base and the default ``rigid_members`` impact) and returns a :class:`CheckGroup`:
its numbers against their tolerances, and the arrays its figure draws. Closed forms come from
:mod:`warp_tensegrity.validation.closed_forms` (the RB chain, the Bessel response, the cubic chain's
solitary wave) and :mod:`warp_tensegrity.validation.dispersion` (Bloch bands); the FB modal sum from
:mod:`warp_tensegrity.validation.linear`. The references take the scene's constants (geometry,
EA, masses) from the :class:`ColumnConfig` and build their networks with
:mod:`warp_tensegrity.validation.reference_column`, never with the engine's scene builder, so an
error there is not shared. Nothing is compared with stored engine output. A check with
``engine=False`` checks a reference alone (the Bloch cell against the chain's closed form).
"""

from __future__ import annotations

import math

import numpy as np

from .closed_forms import RBChain, bessel_compression, power_chain_soliton, rb_chain
from .dispersion import bands, chain_wavenumbers, mode_frequencies, ringing_frequency
from .gallery import Check, CheckGroup
from .linear import modal_analysis
from .preload import preload_force, preload_height, preload_path, scaled_chain
from .reference_column import ReferenceColumn, reference_column
from .striker import striker_chain
from ..engine import simulate_batch
from ..measure import measure_pulse
from ..scene.columns import ColumnConfig
from ..options import RunSettings

__all__ = ["Check", "CheckGroup", "check_bessel", "check_soliton", "check_dispersion", "check_fb_modal", "check_striker", "check_preload",
           "chain_of"]

J1_MAX = 0.5818652242  # max of J_1 (the struck prism's first peak is (v0/c0) J1_MAX)


def chain_of(config: ColumnConfig, prestrain: float) -> RBChain:
    """The RB chain of ``config``'s prism (geometry and material only)."""
    return rb_chain(config.cable_EA, config.radius, config.height, config.unit_mass, prestrain)


def _run(config: ColumnConfig, params: dict, t_end: float, output_interval: float, device: str, **run):
    settings = RunSettings(t_end=t_end, output_interval=output_interval, truncate=False, device=device,
                           precision="fp64", measure="none", **run)
    r = simulate_batch(config, params, settings)
    if int(np.max(r.status)) != 0:
        raise RuntimeError(f"validation run failed (status {r.status}, params {params})")
    return r


# ---------------------------------------------------------------------- 1. Bessel (Schrödinger)
def check_bessel(n_prisms: int = 12, prestrain: float = 0.002, peak_of_p: float = 0.005, t_end: float = 8.0,
                 dt: float = 5e-4, tolerance: float = 1e-4, device: str = "cpu") -> CheckGroup:
    """The whole space-time strain record of a small RB impact against the Bessel form (images
    included). v0 puts the first peak at ``peak_of_p`` x p."""
    cfg = ColumnConfig(n_prisms=n_prisms)
    ch = chain_of(cfg, prestrain)
    v0 = peak_of_p * prestrain * ch.c0 / J1_MAX
    r = _run(cfg, {"prestrain": prestrain, "v0": v0, "base_rigidity": 1.0}, t_end, 0.01, device, dt=dt)
    eng = r.strain[0]
    ref = -bessel_compression(r.time, n_prisms, v0, ch)
    peak = float(np.abs(ref).max())
    err = float(np.abs(eng - ref).max() / peak)
    checks = [Check("bessel_record", "max |engine - Bessel| over every prism and time / Bessel peak",
                    err, 0.0, err, tolerance)]
    notes = [f"{n_prisms} prisms, p = {prestrain:g}, v0 = {v0:.3g} m/s (peak strain {peak / prestrain:.3g} p), "
             f"t_end = {t_end:g} s (the clamp echo included), dt = {r.dt:.3g} s; "
             f"c0 = {ch.c0:.6g} m/s, omega_c = {ch.omega_c:.6g} rad/s, m_eff = {ch.m_eff:.6g} kg, K = {ch.K:.6g} N/m"]
    return CheckGroup("bessel", "Linear RB impact against the Bessel form", checks,
                      {"time": r.time, "engine": eng, "bessel": ref, "chain": ch}, notes)


# ---------------------------------------------------------------------- 2. sonic vacuum (Nesterenko)
def _leading_pulses(q, t, lo, hi):
    """Per prism in [lo, hi): peak time, peak value (parabola over 3 samples) and time FWHM."""
    rows = []
    for j in range(lo, hi):
        y = q[:, j]
        k = int(np.argmax(y))
        y0, y1, y2 = y[k - 1], y[k], y[k + 1]
        off = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
        ym = y1 - 0.25 * (y0 - y2) * off
        half = 0.5 * ym
        if not (0 < k < len(t) - 1 and (y[:k] < half).any() and (y[k:] < half).any()):
            raise RuntimeError(f"prism {j}: the leading pulse is not whole in the record")
        a = k - int(np.argmax(y[k::-1] < half))  # last sample below half before the peak
        b = k + int(np.argmax(y[k:] < half))  # first sample below half after it
        ta = t[a] + (half - y[a]) / (y[a + 1] - y[a]) * (t[a + 1] - t[a])
        tb = t[b - 1] + (y[b - 1] - half) / (y[b - 1] - y[b]) * (t[b] - t[b - 1])
        rows.append((t[k] + off * (t[1] - t[0]), ym, tb - ta))
    return np.array(rows).T


def _soliton_run(cfg, ch, sol, A, dt, device):
    n = cfg.n_prisms
    v0 = (A * cfg.height / sol.amplitude_constant) ** 2 * np.sqrt(ch.k3 / ch.m_eff)
    v_sites = sol.speed_constant * ch.soliton_scale * A / cfg.height
    t_end = (n - 2) / v_sites  # the pulse has passed prism lo; the clamp's echo has not come back to it
    r = _run(cfg, {"prestrain": 0.0, "v0": v0, "base_rigidity": 1.0}, t_end, t_end / 2000, device, dt=dt)
    q = -r.strain[0]
    delta = q / (1.0 + q)  # (h0 - h)/h0: the chain's delta/h0 ((h - h0)/h = -delta/(h0 - delta))
    lo, hi = 5, n - 8  # away from the clamp's echo and from where the pulse forms
    tp, dm, fw = _leading_pulses(delta, r.time, lo, hi)
    speed = -1.0 / np.polyfit(np.arange(lo, hi), tp, 1)[0]  # prisms per second
    amp = float(np.median(dm))
    return {"A": amp, "v0": v0, "c": speed * cfg.height / (ch.soliton_scale * amp),
            "a": amp * cfg.height / ch.soliton_amplitude_scale(v0), "w": float(np.median(fw)) * speed, "speed_sites": speed,
            "time": r.time, "delta": delta, "dt": r.dt}


def check_soliton(n_prisms: int = 30, amplitudes=(0.01, 0.02), dt: float = 4e-3, tolerance_speed: float = 0.01,
                  tolerance_amplitude: float = 0.01, tolerance_width: float = 0.02, device: str = "cpu") -> CheckGroup:
    """The p = 0 RB column's solitary wave against the cubic chain's: speed constant c*, amplitude
    law a* and width, each as the engine's ratio to the chain's at two amplitudes A = delta_max/h0,
    extrapolated linearly to A -> 0 (the prism's geometry adds O(A) terms to the cubic force)."""
    cfg = ColumnConfig(n_prisms=n_prisms)
    ch = chain_of(cfg, 0.0)
    sol = power_chain_soliton()
    runs = [_soliton_run(cfg, ch, sol, A, dt, device) for A in amplitudes]
    (A1, A2) = (runs[0]["A"], runs[1]["A"])

    def extrap(key, ref):
        r1, r2 = runs[0][key] / ref, runs[1][key] / ref
        return (A2 * r1 - A1 * r2) / (A2 - A1)

    checks = []
    for key, ref, tol, name, what in (
            ("c", sol.speed_constant, tolerance_speed, "soliton_speed_constant", "c* = V/(h0^2 sqrt(k3/m_eff) A)"),
            ("a", sol.amplitude_constant, tolerance_amplitude, "soliton_amplitude_law", "a* = delta_max/(v0^2 m_eff/k3)^(1/4)"),
            ("w", sol.width_fwhm, tolerance_width, "soliton_width", "FWHM of delta [prisms]")):
        x = extrap(key, ref)
        checks.append(Check(name, f"{what}, engine extrapolated to A -> 0, relative to the cubic chain",
                            float(x * ref), float(ref), float(abs(x - 1.0)), tol))
    notes = [f"cubic chain (own DOP853 integration): c* = {sol.speed_constant:.6f}, a* = {sol.amplitude_constant:.6f}, "
             f"FWHM = {sol.width_fwhm:.5f} prisms (steady to {sol.spread:.1e}); quasi-continuum c* = sqrt(2/3) = "
             f"{np.sqrt(2 / 3):.6f} ({np.sqrt(2 / 3) / sol.speed_constant - 1:+.2%})",
             "engine at each A: " + "; ".join(
                 f"A = {r['A']:.4f}: c/c* = {r['c'] / sol.speed_constant:.4f}, a/a* = {r['a'] / sol.amplitude_constant:.4f}, "
                 f"w/w* = {r['w'] / sol.width_fwhm:.4f}" for r in runs),
             f"{n_prisms} prisms, p = 0, dt = {dt:g} s, k3 = {ch.k3:.6g} N/m^3, m_eff = {ch.m_eff:.6g} kg"]
    return CheckGroup("soliton", "Sonic-vacuum solitary wave against the cubic chain", checks,
                      {"runs": runs, "soliton": sol, "chain": ch, "height": cfg.height}, notes)


# ---------------------------------------------------------------------- 3. dispersion
def check_dispersion(n_prisms: int = 20, prestrain: float = 0.002, peak_of_p: float = 0.01, t_end: float = 6.0,
                     dt: float = 1e-3, n_k: int = 61, tolerance_c0: float = 1e-3, tolerance_speed: float = 5e-3,
                     modes_prisms: int = 8, modes_t_end: float = 8.0, modes_output: float = 0.02,
                     tolerance_modes: float = 2e-4,
                     device: str = "cpu") -> CheckGroup:
    """Bloch bands FB and RB of the independent cell (:mod:`.dispersion`): the mode frequencies of a
    simulated ``modes_prisms``-prism column, RB and FB, against them at the column's k_j (engine); the RB
    branch and its long-wave limit against the chain's closed form (reference only); the simulated RB
    impact's speed (the datasets' ``speed`` measure) against the same measure on the Bessel form
    (engine; a time of flight along the column, it moves by only 5e-5 under a 5 % error in the struck
    base's mass: the record and mode checks see that one)."""
    cfg = ColumnConfig(n_prisms=n_prisms)
    ch = chain_of(cfg, prestrain)
    h0 = cfg.height
    k_long = 1e-3 / h0
    c_long = bands(cfg, prestrain, 1.0, k=[k_long]).long_wave_speed()
    rb, fb = bands(cfg, prestrain, 1.0, n_k=n_k), bands(cfg, prestrain, 0.0, n_k=n_k)
    exact = ch.omega_c * np.abs(np.sin(rb.k * h0 / 2))
    band_err = float(np.abs(rb.omega_symmetric[:, 0] - exact).max() / ch.omega_c)
    v0 = peak_of_p * prestrain * ch.c0 / J1_MAX
    params = {"prestrain": np.full(2, prestrain), "v0": np.full(2, v0), "base_rigidity": np.array([1.0, 0.0])}
    r = _run(cfg, params, t_end, 0.01, device, dt=dt)
    ref = -bessel_compression(r.time, n_prisms, v0, ch)
    m_sim = measure_pulse(r.strain, r.time, h0)
    m_ref = measure_pulse(ref, r.time, h0)
    v_sim, v_ref = float(m_sim["speed"][0]), float(m_ref["speed"])
    cut = [ringing_frequency(r.strain[i], r.time) for i in range(2)]
    t50 = np.arange(0.0, 14.0, 0.01)  # the paper's 50 prisms, Bessel form only: the lag shrinks with length
    v50 = float(measure_pulse(-bessel_compression(t50, 50, v0, ch), t50, h0)["speed"])
    # the modes: a short column rung long enough to hold each of its modes, against the bands at its k_j
    mcfg = ColumnConfig(n_prisms=modes_prisms)
    rm = _run(mcfg, params, modes_t_end, modes_output, device, dt=dt)  # 400 samples: the pencil's SVD stays small
    k_j = chain_wavenumbers(modes_prisms, h0)
    modes = {}
    for i, (name, beta) in enumerate((("rb", 1.0), ("fb", 0.0))):
        w_sim = mode_frequencies(rm.strain[i], rm.time, modes_prisms)
        w_ref = bands(cfg, prestrain, beta, k=k_j).omega_symmetric[:, 0]
        rel = w_sim / w_ref - 1.0
        j = int(np.argmax(np.abs(rel)))
        modes[name] = (w_sim, w_ref, float(np.abs(rel[j])), j)
    checks = [
        Check("dispersion_rb_modes", f"max over the {modes_prisms} modes of |simulated RB column's frequency "
              "(matrix pencil) / the RB Bloch branch at k_j h0 = (2j-1) pi/(2N) - 1|",
              float(modes["rb"][0][modes["rb"][3]]), float(modes["rb"][1][modes["rb"][3]]), modes["rb"][2],
              tolerance_modes),
        Check("dispersion_fb_modes", f"the same, FB column against the FB soft symmetric branch",
              float(modes["fb"][0][modes["fb"][3]]), float(modes["fb"][1][modes["fb"][3]]), modes["fb"][2],
              tolerance_modes),
        Check("dispersion_long_wave", "reference only: RB omega/k at k h0 = 1e-3 (Bloch cell) against c0 = "
              "h0 sqrt(K/m_eff)", c_long, ch.c0, abs(c_long / ch.c0 - 1.0), tolerance_c0, engine=False),
        Check("dispersion_rb_branch", "reference only: max over k of |RB symmetric branch - omega_c "
              "|sin(k h0/2)|| / omega_c", band_err, 0.0, band_err, 1e-6, engine=False),
        Check("dispersion_speed_measure", "'speed' measure of the simulated RB record against the same measure "
              "of the Bessel record", v_sim, v_ref, abs(v_sim / v_ref - 1.0), tolerance_speed),
    ]
    notes = [f"modes: {modes_prisms} prisms, p = {prestrain:g}, v0 = {v0:.3g} m/s, t_end = {modes_t_end:g} s, "
             f"dt = {rm.dt:g} s; simulated / Bloch - 1 per mode, RB: "
             + " ".join(f"{x:+.1e}" for x in modes["rb"][0] / modes["rb"][1] - 1) + "; FB: "
             + " ".join(f"{x:+.1e}" for x in modes["fb"][0] / modes["fb"][1] - 1)
             + " (the FB column's own end levels put its soft modes up to ~3e-5 off the periodic column's)",
             "dispersion_long_wave and dispersion_rb_branch check the reference only (the Bloch cell against the "
             "chain's closed form): no engine run enters them",
             f"speed: {n_prisms} prisms, p = {prestrain:g}, v0 = {v0:.3g} m/s, t_end = {t_end:g} s, dt = {r.dt:g} s",
             f"time-of-flight 'speed' of the Bessel record = {v_ref / ch.c0:.4f} c0: the leading peak lags the "
             f"long-wave front (its arrival order 2n+1 grows with a (2n+1)^(1/3) delay); {v50 / ch.c0:.4f} c0 over "
             f"the paper's 50 prisms",
             f"simulated FB speed {float(m_sim['speed'][1]):.5g} m/s against the FB soft branch's long-wave "
             f"speed {fb.long_wave_speed():.5g} m/s",
             f"ringing of the struck prism: RB {cut[0]:.4g} rad/s against omega_c = {ch.omega_c:.4g} rad/s "
             f"({cut[0] / ch.omega_c - 1:+.2%}); FB {cut[1]:.4g} rad/s"]
    data = {"rb": rb, "fb": fb, "speed": [v_sim, float(m_sim["speed"][1])], "cutoff": cut, "c0": ch.c0,
            "omega_c": ch.omega_c, "speed_bessel": v_ref, "k_modes": k_j,
            "modes": {k: (v[0], v[1]) for k, v in modes.items()}}
    return CheckGroup("dispersion", "Linear dispersion of the periodic column", checks, data, notes)


# ---------------------------------------------------------------------- 4. FB modal sum
def modal_strain(column: ReferenceColumn, time) -> np.ndarray:
    """Linear strain history (n_time, n_prisms) of ``column``'s impact (a
    :class:`~.reference_column.ReferenceColumn`) as a sum over the modes of
    :func:`warp_tensegrity.validation.linear.modal_analysis`: u(t) = sum_n phi_n (phi_n^T M v) sin(w_n t)/w_n,
    strain = the change of each prism's mean base height over h0."""
    net = column.network
    r = modal_analysis(net)
    if np.any(r.omega2 <= 1e-10 * r.omega2.max()):
        raise ValueError("the column has zero-frequency modes (unstressed): no modal sum")
    w = r.omega
    amp = np.einsum("mni,ni,n->m", r.shapes, column.velocity, net.node_mass)  # phi^T M v (lumped masses)
    uz = np.einsum("m,mn,tm->tn", amp, r.shapes[:, :, 2], np.sin(np.outer(time, w)) / w)
    zl = uz[:, column.level_nodes].mean(axis=-1)
    return np.diff(zl, axis=1) / column.height


def check_fb_modal(n_prisms: int = 8, prestrain: float = 0.002, v0: float = 1e-7, t_end: float = 3.0,
                   t_end_twist: float = 1.0, dt_twist: float = 4e-5, tolerance: float = 1e-4,
                   device: str = "cpu") -> CheckGroup:
    """The FB column's small impact (no 1-D reduction) against the modal sum of validation.linear on the
    column rebuilt from the closed forms (:mod:`.reference_column`, not the engine's scene builder), under
    two impacts: 'rigid_members' (the default: the soft, axial-torsional modes; default accuracy, ``t_end``)
    and 'end_twist' (the struck base's nodes pushed apart too: the base members' breathing modes, up to
    ~150 rad/s, which hold the base stiffness; ``t_end_twist`` at ``dt_twist``, RATTLE's phase error
    growing as omega^3 dt^2 t)."""
    checks, data, notes = [], {}, []
    for impact, name, t1, run in (("rigid_members", "fb_modal_record", t_end, {"output_interval": 0.01}),
                                  ("end_twist", "fb_modal_end_twist", t_end_twist,
                                   {"output_interval": 0.005, "dt": dt_twist})):
        cfg = ColumnConfig(n_prisms=n_prisms, impact_admissibility=impact)
        out = run.pop("output_interval")
        r = _run(cfg, {"prestrain": prestrain, "v0": v0, "base_rigidity": 0.0}, t1, out, device, **run)
        col = reference_column(n_prisms, cfg.radius, cfg.height, cfg.cable_EA, cfg.unit_mass, prestrain, 0.0, v0=v0,
                               handedness=cfg.handedness, end_base_mass=cfg.end_base_mass, impact=impact)
        ref = modal_strain(col, r.time)
        err = float(np.abs(r.strain[0] - ref).max() / np.abs(ref).max())
        checks.append(Check(name, f"'{impact}' impact: max |engine - modal sum| over every prism and time / "
                            "modal peak", err, 0.0, err, tolerance))
        notes.append(f"{impact}: {n_prisms} prisms, p = {prestrain:g}, v0 = {v0:g} m/s (peak strain "
                     f"{np.abs(ref).max() / prestrain:.2g} p), t_end = {t1:g} s, dt = {r.dt:.3g} s"
                     + (" (default accuracy)" if "dt" not in run else ""))
        suffix = "" if not data else "_end_twist"
        data.update({f"time{suffix}": r.time, f"engine{suffix}": r.strain[0], f"modal{suffix}": ref})
    notes.append("the reference network is rebuilt from the paper's geometry and the closed-form self-stress "
                 "(reference_column), so an error in the engine's scene builder is not shared by it")
    return CheckGroup("fb_modal", "FB small impact against the modal sum", checks, data, notes)


# ---------------------------------------------------------------------- 5. a striker on the linear chain
def check_striker(n_prisms: int = 12, prestrain: float = 0.002, striker_mass: float = 0.2, peak_of_p: float = 0.005,
                  t_end: float = 1.5, dt: float = 1e-3, device: str = "cpu"):
    """The engine's striker on a small linear RB impact against :func:`striker_chain`: the striker's
    velocity record, the energy in the column (what the striker handed over), the contact force while
    they first touch and the time it leaves. v0 as in the Bessel check (first peak ``peak_of_p`` x p
    under the velocity impact)."""
    cfg = ColumnConfig(n_prisms=n_prisms, impact="striker", striker_mass=striker_mass)
    ch = chain_of(cfg, prestrain)
    v0 = peak_of_p * prestrain * ch.c0 / J1_MAX
    r = _run(cfg, {"prestrain": prestrain, "v0": v0, "base_rigidity": 1.0}, t_end, 0.01, device, dt=dt)
    eng = r.info["striker"]
    ref = striker_chain(ch, n_prisms, striker_mass, v0, r.time)
    e_col = r.kinetic_energy[0] + r.elastic_energy[0] - r.elastic_energy[0, 0]
    t_sep = ref.separations[0] if ref.separations else np.nan
    err_v = float(np.abs(eng["velocity"][0] - ref.velocity).max() / v0)
    err_e = float(np.abs(e_col - ref.column_energy).max() / ref.column_energy.max())
    # the recorded force is the step's mean (momentum change / dt): the reference at mid-step
    first = (r.time > 0) & (r.time < t_sep - 2 * r.dt)
    f_mid = striker_chain(ch, n_prisms, striker_mass, v0, r.time[first] - 0.5 * r.dt).force
    err_f = float(np.abs(eng["force"][0][first] - f_mid).max() / ref.force.max())
    t_eng = float(eng["separation_time"][0])
    err_t = abs(t_eng - t_sep) / t_sep
    checks = [
        Check("striker_velocity", "max |engine - chain| of the striker's velocity over the record / v0",
              err_v, 0.0, err_v, 1e-4),
        Check("striker_energy", "max |engine - chain| of the column's energy (what the striker handed over) / its peak",
              err_e, 0.0, err_e, 1e-4),
        Check("striker_force", "max |engine - chain| of the contact force while first touching / its peak",
              err_f, 0.0, err_f, 1e-3),
        Check("striker_separation", "separation time, relative (the engine's resolution is dt)", t_eng, t_sep, err_t,
              2.0 * r.dt / t_sep),
    ]
    notes = [f"{n_prisms} prisms, RB, p = {prestrain:g}, striker M = {striker_mass:g} kg (m_eff/2 = "
             f"{0.5 * ch.m_eff:.4g} kg), v0 = {v0:.3g} m/s, V1 = {ref.blow_speed:.4g} m/s, dt = {r.dt:.3g} s; "
             f"the chain: separations at {', '.join(f'{t:.4f}' for t in ref.separations)} s, contacts again at "
             f"{', '.join(f'{t:.4f}' for t in ref.contacts) or 'none'} s; the engine: {int(eng['recontacts'][0])} "
             f"contact(s) again; energy handed over {ref.column_energy[-1]:.4g} J of the striker's "
             f"{0.5 * striker_mass * v0**2:.4g} J"]
    return CheckGroup("striker", "A striker on the linear RB chain", checks,
                      {"time": r.time, "engine_velocity": eng["velocity"][0], "chain_velocity": ref.velocity,
                       "engine_force": eng["force"][0], "chain_force": ref.force, "engine_energy": e_col,
                       "chain_energy": ref.column_energy, "v0": v0, "separations": ref.separations}, notes)



# ---------------------------------------------------------------------- 5. end preload (issue 34)
def check_preload(n_prisms: int = 8, prestrain: float = 0.01, load_of_tension: float = 3.0, peak_of_p: float = 1e-4,
                  t_end: float = 1.0, tolerance_static: float = 1e-7, tolerance_speed: float = 1e-3,
                  device: str = "cpu"):
    """The engine's preloaded RB column against :func:`.preload.preload_path`: F0 = ``load_of_tension`` x EA p.
    Two columns: one at rest (it must stay in its static state: its height and twist against the
    closed form), one struck by a small impact (its strain record against the chain's Bessel form,
    the chain's frequency fitted: the speed against the tangent-stiffness speed)."""
    from scipy.optimize import minimize_scalar

    cfg = ColumnConfig(n_prisms=n_prisms)
    EA = cfg.cable_EA
    F0 = load_of_tension * EA * prestrain
    path = preload_path(F0, EA, cfg.radius, cfg.height, cfg.unit_mass, prestrain)
    ch = path.chain()
    c_chain = ch.c0  # h sqrt(K_t/m_eff): the chain's speed in loaded heights per second
    v0 = peak_of_p * prestrain * c_chain / J1_MAX
    r = _run(cfg, {"prestrain": prestrain, "base_rigidity": 1.0, "preload": F0, "v0": np.array([0.0, v0])},
             t_end, 0.01, device)
    f = r.feasibility
    h_eng = float(np.mean(f["prism_height_ratio_min"][0])) * cfg.height
    phi_eng = float(np.mean(f["prism_twist_last"][0]))
    still = float(np.abs(r.strain[0]).max())
    eng = r.strain[1]
    ref = -bessel_compression(r.time, n_prisms, v0, ch)
    peak = float(np.abs(ref).max())

    def misfit(scale):  # the engine record against the Bessel form of a chain of frequency scale x omega_c
        return float(np.abs(eng + bessel_compression(r.time, n_prisms, v0, scaled_chain(ch, scale))).max())

    fit = minimize_scalar(misfit, bounds=(0.9, 1.1), method="bounded", options={"xatol": 1e-9})
    speed = path.speed * fit.x
    checks = [
        Check("preload_height", "|h_engine - h(F0)| / (h0 - h(F0)), the static shortening", h_eng, path.height,
              abs(h_eng - path.height) / (cfg.height - path.height), tolerance_static),
        Check("preload_twist", "|phi_engine - phi(F0)| / (phi(F0) - 5 pi/6), the static twist", phi_eng, path.twist,
              abs(phi_eng - path.twist) / (path.twist - cfg.twist), tolerance_static),
        Check("preload_at_rest", "max |strain| of the preloaded column left at rest / p", still / prestrain, 0.0,
              still / prestrain, tolerance_static),
        Check("preload_speed", "|c_fit - c_t| / c_t: the struck column's speed (Bessel fit) against "
              "h0 sqrt(K_t/m_eff)", speed, path.speed, abs(fit.x - 1.0), tolerance_speed),
        Check("preload_record", "max |engine - Bessel(K_t, m_eff)| over every prism and time / peak",
              misfit(1.0) / peak, 0.0, misfit(1.0) / peak, 5.0 * tolerance_speed),
    ]
    base = rb_chain(EA, cfg.radius, cfg.height, cfg.unit_mass, prestrain)
    notes = [f"{n_prisms} prisms, RB, p = {prestrain:g}, F0 = {F0:.6g} N ({load_of_tension:g} EA p): closed form "
             f"phi = {path.twist:.9g} rad, h/h0 = {path.height / cfg.height:.9g}, K_t = {path.stiffness:.6g} N/m "
             f"(unloaded K = {base.K:.6g}), m_eff = {path.m_eff:.6g} kg (unloaded {base.m_eff:.6g}), "
             f"c_t = {path.speed:.6g} m/s (unloaded c0 = {base.c0:.6g}); v0 = {v0:.3g} m/s, dt = {r.dt:.3g} s"]
    phis = np.linspace(cfg.twist, math.pi - 0.02, 200)
    return CheckGroup("preload", "End preload: static compression and small waves on the loaded RB column", checks,
                      {"time": r.time, "engine": eng, "bessel": ref, "path": path, "phi": phis,
                       "force": preload_force(phis, EA, cfg.radius, cfg.height, prestrain),
                       "height": preload_height(phis, cfg.radius, cfg.height),
                       "h0": cfg.height, "engine_height": h_eng, "F0": F0}, notes)
