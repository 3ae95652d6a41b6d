"""How a sweep stores its energy histories (run.energy_precision, run.compress_energy; issue 33 item 5):
the storage changes those histories only, to their float32 rounding, never a measure (every
measure is taken on the device record before the dataset is built)."""

import netCDF4
import numpy as np

from warp_tensegrity.io import ENERGY_RECORDS, open_sweep

from warp_tensegrity import cli

SPEC = """
[scene]
n_prisms = 5

[sweep]
cases = [
  { prestrain = 0.0,   v0 = 0.004, base_rigidity = 0.0 },
  { prestrain = 0.002, v0 = 0.008, base_rigidity = 1.0 },
]

[run]
t_end = 0.1
output_interval = 1.0e-4  # 1,001 outputs: records big enough to be compressed (io._encoding)
device = "cpu"
"""

FP32 = ("kinetic_energy", "station_energy", "end_energy")  # 'auto': float32; elastic_energy keeps float64


def _run(d, extra: str):
    d.mkdir()
    out, spec = d / "out.nc", d / "spec.toml"
    spec.write_text(SPEC + extra)
    assert cli.main(["run", str(spec), "-o", str(out), "--no-progress"]) == 0
    return out


def test_energy_storage_changes_the_histories_only(tmp_path):
    exact = _run(tmp_path / "fp64", 'energy_precision = "fp64"\ncompress_energy = true\n')
    auto = _run(tmp_path / "auto", "")
    a, b = open_sweep(exact), open_sweep(auto)
    assert set(a.data_vars) == set(b.data_vars) and set(FP32) < set(a.data_vars)
    for k in a.data_vars:
        x, y = a[k].values, b[k].values
        if k in FP32:
            assert x.dtype == np.float64 and y.dtype == np.float32, k
            assert np.array_equal(x.astype(np.float32), y, equal_nan=True), k  # the float32 rounding, nothing else
            assert "float32" in b[k].attrs["comment"]
        else:  # the measures, their errors and flags, elastic_energy: byte for byte
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), k
    assert (a.attrs["energy_precision"], a.attrs["compress_energy"]) == ("fp64", 1)
    assert (b.attrs["energy_precision"], b.attrs["compress_energy"]) == ("auto", 0)
    with netCDF4.Dataset(exact) as fa, netCDF4.Dataset(auto) as fb:  # compressed only where asked
        for k in ENERGY_RECORDS:
            assert fa[k].filters()["zlib"] and not fb[k].filters()["zlib"], k
