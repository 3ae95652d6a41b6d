"""The analysis notebooks (analysis/*.ipynb) cannot rot.

Here, in the normal test run: each .ipynb is paired with its .py (jupytext percent format) and
has the same code.

Their execution is CI's own step, ``bash .ci/notebooks`` (nbmake, two at a time): each runs in a
fresh kernel with its inputs pointed at files that do not exist yet, so the notebook makes them
itself by running the command line (sweeps/paper_2017.toml, ~15 s on the CPU, unless .ci/test's
pytest step already ran that command and the step passes its output on; sweeps/ci_small.toml for
the phase diagrams, seconds). Figures and CSVs go to a temporary directory
(``WT_NOTEBOOK_OUT``); nothing in the repository is written. That step then runs the ``notebook``
tests below (deselected otherwise), which check what the notebooks made.
"""

import json
import os
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
jupytext = pytest.importorskip("jupytext")

ROOT = Path(__file__).resolve().parent.parent
ANALYSIS = ROOT / "analysis"
NOTEBOOKS = {
    "paper_2017": ["paper_fig4_fb_p0", "paper_fig5_rb_p0", "paper_fig6_fb_p0002", "paper_fig7_rb_p0002",
                   "paper_spacetime", "paper_conventions", "paper_sonic_vacuum", "paper_linear_speeds"],
    "phase_diagrams": ["phase_amplitude", "phase_speed", "phase_width_maps", "phase_width", "phase_speed_lines",
                       "phase_nonlinearity", "phase_compactness", "phase_regimes"],
    "lens": ["lens_calibration", "lens_prestrain", "lens_pulses", "lens_focal_map", "lens_focus_moving"],
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


def _notebook_out() -> Path:
    out = os.environ.get("WT_NOTEBOOK_OUT")
    if not out:
        pytest.fail("run the notebooks first: bash .ci/notebooks (it sets WT_NOTEBOOK_OUT)")
    return Path(out)


@pytest.mark.notebook
@pytest.mark.parametrize("name", sorted(NOTEBOOKS))
def test_notebook_outputs(name):
    """What nbmake's run of the notebook made (.ci/notebooks points every output at WT_NOTEBOOK_OUT)."""
    out = _notebook_out()
    made = {p.stem for p in (out / "figures").glob("*.png")}
    assert set(NOTEBOOKS[name]) <= made, f"missing figures: {set(NOTEBOOKS[name]) - made}"
    if name == "paper_2017":
        assert (out / "paper_2017.nc").exists()
        assert (out / "data" / "paper_2017_table.csv").exists()
    elif name == "lens":
        assert (out / "lens_ci.nc").exists()  # its CPU fallback: sweeps/lens_ci.toml
    else:
        assert (out / "phase_ci_small.nc").exists()
    assert not list(ANALYSIS.glob("*.nc.shards")) and not list(ANALYSIS.glob("*.nc.sweep"))
