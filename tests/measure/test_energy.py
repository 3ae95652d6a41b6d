"""Energy measures (warp_tensegrity.measure.energy, docs/measurements.md "Energy measures"): the
device's energy-parts record against a NumPy evaluation of the state it was taken from, its parts
against the independent total energy record (conservation), and the device's energy shares against
the NumPy reference on the stored record (fp64, 1e-12)."""

import numpy as np
import pytest

from warp_tensegrity import simulate_batch
from warp_tensegrity.measure.energy import end_energy_share, energy_parts, part_nodes, pulse_energy_share, section_power
from warp_tensegrity.measure.pulse_core import measure_pulse, measurement_window
from warp_tensegrity.options import RunSettings, SettingsError
from warp_tensegrity.policy.decide import check_batch_arguments
from warp_tensegrity.scene.batch import column_batch, column_params
from warp_tensegrity.scene.columns import ColumnConfig
from warp_tensegrity.scene.coupling import mass_entries
from warp_tensegrity.types import Path

# FB, elastic and rigid bases, prestressed; strong enough that cables go slack (the bilinear law's switch)
PARAMS = {"prestrain": [0.002, 0.01, 0.005], "v0": [0.3, 0.05, 0.1], "base_rigidity": [0.0, 0.5, 1.0]}


def _parts_run(n: int, station: int, k: int, n_out: int = 6, every: int = 120):
    """(records (below, end, kinetic, elastic) each (n_out, B), NumPy parts of the state at each output)."""
    from warp_tensegrity.sim.integrate import Integrator

    cfg = ColumnConfig(n_prisms=n)
    batch = column_batch(cfg, column_params(cfg, PARAMS))
    integ = Integrator(batch, RunSettings(device="cpu", precision="fp64"), 2e-4, every, n_out, path=Path.STAGED,
                       energy_parts=part_nodes(n, station, k))
    _, _, m_self, m_cross, _, _ = mass_entries(batch)
    partner = mass_entries(batch)[1]
    X, cab = batch.positions, batch.cables
    ref = []
    integ.initialize()
    for slot in range(n_out):
        if slot:
            integ.advance(every)
        u = integ.data.u.numpy().transpose(1, 0, 2)
        v = integ.data.v.numpy().transpose(1, 0, 2)
        ref.append(energy_parts(u, v, m_self, cab, X[cab[:, 1]] - X[cab[:, 0]], batch.cable_EA,
                                batch.cable_EA_compression, batch.cable_rest_length, *part_nodes(n, station, k),
                                m_cross=m_cross, partner=partner))
    rec = [a.numpy() for a in (integ.energy_below, integ.energy_end, integ.kinetic, integ.elastic)]
    return rec, np.array(ref)  # ref: (n_out, 2, B)


def test_parts_add_up_to_the_total_energy_and_match_numpy():
    """The two sides of a cut hold the column's energy above the reference (kinetic + elastic -
    elastic at u = 0, the record_energy kernel's totals), and each side is the NumPy sum over its
    nodes and members of the same state, at every output."""
    n, s = 5, 1
    (below, end, ke, ee), ref = _parts_run(n, s, n - s - 1)
    e_imp = ke[0]
    assert np.all(e_imp > 0)
    total = ke + ee - ee[0]
    assert np.all(np.abs(below).max(axis=0) > 1e-3 * e_imp) and np.all(np.abs(end).max(axis=0) > 0.1 * e_imp)
    # round-off of the prestress energy the total carries (the parts never hold it)
    np.testing.assert_allclose(below + end, total, rtol=0, atol=1e-12 * ee[0].max())
    np.testing.assert_allclose(below, ref[:, 0], rtol=0, atol=1e-12 * e_imp.max())
    np.testing.assert_allclose(end, ref[:, 1], rtol=0, atol=1e-12 * e_imp.max())


def test_parts_leave_out_the_middle():
    """With the end part shorter than the column above the station, the prisms between them belong
    to neither part: both still match NumPy."""
    n, s, k = 5, 0, 2
    (below, end, ke, ee), ref = _parts_run(n, s, k, n_out=4)
    assert np.all(end[-1] > 0)
    np.testing.assert_allclose(below, ref[:, 0], rtol=0, atol=1e-12 * ke[0].max())
    np.testing.assert_allclose(end, ref[:, 1], rtol=0, atol=1e-12 * ke[0].max())
    assert np.all(below[-1] + end[-1] < (ke + ee - ee[0] - 1e-3 * ke[0])[-1])  # the middle holds energy


def test_shares_match_the_numpy_reference():
    """The device's energy shares equal the NumPy reference computed from the stored records and
    the NumPy pulse measures (fp64, 1e-12); the pulse carries most of the impact energy through the
    station and the end part keeps some."""
    cfg = ColumnConfig(n_prisms=12)
    r = simulate_batch(cfg, {"prestrain": [0.002, 0.004], "v0": [0.1, 0.1], "base_rigidity": [1.0, 1.0]},
                       RunSettings(t_end=0.45, device="cpu", precision="fp64", fused=False, truncate=False,
                                   energy_end_prisms=3))
    m = r.measurements
    host = measure_pulse(r.strain, r.time, cfg.height)
    s = (cfg.n_prisms - 1) // 2
    pulse = pulse_energy_share(r.station_energy, r.kinetic_energy[:, 0], r.time, host["arrival_time"],
                               host["peak_time"], host["width_10"], s, measurement_window(cfg.n_prisms))
    end = end_energy_share(r.end_energy, r.kinetic_energy[:, 0], r.time, host["speed"], cfg.height, cfg.n_prisms, 3)
    assert np.all(np.isfinite(pulse)) and np.all((pulse > 0.5) & (pulse < 1.0))
    assert np.all((end > 0) & (end < 1))
    np.testing.assert_allclose(m["pulse_energy_share"], pulse, rtol=1e-12)
    np.testing.assert_allclose(m["end_energy_share"], end, rtol=1e-12)
    assert np.all(m["pulse_energy_share_sensitivity"] == 0)
    ds = r.to_xarray(cfg)
    assert ds["pulse_energy_share"].attrs["units"] == "1" and ds["station_energy"].attrs["units"] == "J"
    assert ds.attrs["energy_station"] == s and ds.attrs["energy_end_prisms"] == 3


def test_a_station_outside_the_column_is_refused():
    cfg = ColumnConfig(n_prisms=4)
    with pytest.raises(SettingsError, match=r"energy_station = 4: must be < the scene's n_prisms = 4"):
        check_batch_arguments("decide", cfg, {}, RunSettings(energy_station=4))


def test_flux_through_the_section_integrates_to_the_energy_passed():
    """Conservation through the station's section: the energy flux into the clamp side (member
    forces times the velocities of their ends across the section, bar forces from the state's
    constraint solve: energy.section_power, NumPy), integrated over time (trapezoids over every
    step), equals the change of the recorded energy on that side to the integration error."""
    from warp_tensegrity.sim.integrate import Integrator

    n, s, steps, dt = 4, 1, 1500, 2e-4
    cfg = ColumnConfig(n_prisms=n)
    batch = column_batch(cfg, column_params(cfg, PARAMS))
    below_node = part_nodes(n, s, 1)[0]
    integ = Integrator(batch, RunSettings(device="cpu", precision="fp64"), dt, 1, steps + 1, path=Path.STAGED,
                       energy_parts=part_nodes(n, s, 1))
    X = batch.positions
    power = []
    integ.initialize()
    for k in range(steps + 1):
        if k:
            integ.step()
        x = X[None] + integ.data.u.numpy().transpose(1, 0, 2)
        v = integ.data.v.numpy().transpose(1, 0, 2)
        power.append(section_power(x, v, batch.fixed, batch.node_mass, batch.constraints, batch.cables, batch.cable_EA,
                                   batch.cable_EA_compression, batch.cable_rest_length, below_node,
                                   batch.constraint_active))
    power = np.array(power)
    flux = np.concatenate([np.zeros((1, power.shape[1])), np.cumsum(0.5 * dt * (power[1:] + power[:-1]), axis=0)])
    below, ke0 = integ.energy_below.numpy(), integ.kinetic.numpy()[0]
    assert np.all(below[-1] > 0.05 * ke0)  # the pulse has brought energy through the section
    np.testing.assert_allclose(flux, below - below[0], rtol=0, atol=1e-3 * below[-1].max())
