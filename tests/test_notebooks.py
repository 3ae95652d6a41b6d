"""Execute the analysis notebooks (analysis/*.ipynb) end to end, so they cannot rot.

Each runs in a fresh kernel with its inputs pointed at files that do not exist yet, so the notebook
makes them itself by running the command line (sweeps/paper_2017.toml, ~15 s on the CPU;
sweeps/ci_small.toml for the phase diagrams, seconds). Figures and CSVs go to a temporary directory;
nothing in the repository is written. Also checks that each .ipynb is paired with its .py
(jupytext percent format) and has the same code.
"""

import json
import os
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
jupytext = pytest.importorskip("jupytext")

ROOT = Path(__file__).resolve().parent.parent
ANALYSIS = ROOT / "analysis"
NOTEBOOKS = {
    "paper_2017": ["paper_fig4_fb_p0", "paper_fig5_rb_p0", "paper_fig6_fb_p0002", "paper_fig7_rb_p0002",
                   "paper_spacetime", "paper_conventions", "paper_sonic_vacuum", "paper_linear_speeds"],
    "phase_diagrams": ["phase_amplitude", "phase_speed", "phase_width_maps", "phase_width", "phase_speed_lines",
                       "phase_nonlinearity", "phase_compactness", "phase_regimes"],
}


def _code(cells):
    return [c["source"] if isinstance(c["source"], str) else "".join(c["source"])
            for c in cells if c["cell_type"] == "code"]


@pytest.mark.parametrize("name", sorted(NOTEBOOKS))
def test_notebook_is_paired_with_its_script(name):
    ipynb = json.loads((ANALYSIS / f"{name}.ipynb").read_text())
    assert ipynb["metadata"]["jupytext"]["formats"] == "ipynb,py:percent"
    script = jupytext.read(ANALYSIS / f"{name}.py")
    assert _code(ipynb["cells"]) == _code(script.cells), f"{name}.ipynb and {name}.py differ: run jupytext --sync"


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(NOTEBOOKS))
def test_notebook_executes(name, tmp_path, monkeypatch):
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("WT_DEVICE", "cpu")
    monkeypatch.setenv("WT_FIG_DIR", str(tmp_path / "figures"))
    monkeypatch.setenv("WT_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setenv("WT_PAPER_NC", str(tmp_path / "paper_2017.nc"))  # missing: the notebook runs the CLI
    monkeypatch.setenv("WT_PAPER_RECOMPUTE", "0")
    monkeypatch.setenv("WT_PHASE_NC", str(tmp_path / "phase_missing.nc"))  # missing: ci_small fallback
    monkeypatch.setenv("WT_PHASE_FALLBACK_NC", str(tmp_path / "phase_ci_small.nc"))
    nb = nbformat.read(ANALYSIS / f"{name}.ipynb", as_version=4)
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(ANALYSIS)}})
    client.execute()
    made = {p.stem for p in (tmp_path / "figures").glob("*.png")}
    assert set(NOTEBOOKS[name]) <= made, f"missing figures: {set(NOTEBOOKS[name]) - made}"
    if name == "paper_2017":
        assert (tmp_path / "paper_2017.nc").exists()
        assert (tmp_path / "data" / "paper_2017_table.csv").exists()
    else:
        assert (tmp_path / "phase_ci_small.nc").exists()
    assert not list(ANALYSIS.glob("*.nc.shards"))
