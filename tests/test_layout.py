"""Import contracts of the package layout (docs/architecture.md): no cycles, no upward imports,
import chains at most MAX_CHAIN modules long, and reading a spec does not load Warp.

Edges are every ``import`` / ``from ... import`` of a package module: at module level, inside
functions and under ``if TYPE_CHECKING:`` alike (an annotation-only import still ties two modules
together; issue 26). Hand-written rather than
import-linter: import-linter has layers and independence contracts but no chain-length contract,
and this reads the same graph for all three checks."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = "warp_tensegrity"
MAX_CHAIN = 11
"""Issue 15 held chains to 7 modules by leaving annotation-only imports (TYPE_CHECKING) out of the
graph, re-exporting through shims and importing inside functions. Issue 26 counts every edge and
takes the shims out, so the depth is now that of the data path's eight layers (LAYERS): e.g.
cli -> validation -> validation.checks -> engine -> integrate -> kernels.lanes -> model ->
scene.coupling -> scene.batch -> arguments -> options. A guard against new depth, not a target."""

# Lowest layer first, in the order of the data path (docs/architecture.md): a module may import
# lower layers and its own layer's modules (acyclic), never a higher one.
LAYERS = [
    # foundation: names, options, arguments, start-up, provenance
    {"types", "options", "options_lens", "options_docs", "tomlread", "arguments", "_version", "provenance", "runtime",
     "overrides", "sweep.errors"},
    # scene: networks, columns, batches (NumPy)
    {"scene.network", "scene.impact", "scene.sparse", "scene.columns", "scene.batch", "scene.coupling",
     "scene.base_modes", "scene"},
    # policy: the run decided once, and its price
    {"policy", "policy.accuracy", "policy.cost", "policy.lane_fit", "policy.paths", "policy.decide"},
    # sim: the device model, kernels, the Integrator
    {"kernels.common", "kernels.coop", "kernels.staged", "kernels.staged_solver", "kernels.fused", "kernels.lane_ops",
     "kernels.lane_funcs", "kernels.lane_rigid", "kernels.lanes", "kernels", "model", "integrate"},
    # measure
    {"measure.pulse_core", "measure.pulse", "measure", "measure.device_funcs", "measure.device_kernels",
     "measure.device", "measure.nan_reasons"},
    # a run's datasets, its execution and its calibration
    {"io", "result", "engine", "policy.calibrate"},
    # applications: sweeps, the lens, the validation gallery, figures, the public facade
    {"sweep.manifest", "sweep.budget", "sweep.progress", "sweep.parse", "sweep.spec", "sweep.store", "sweep.status",
     "sweep.plan", "sweep.shard", "sweep.dask", "sweep.run", "sweep", "lens.host", "lens.design", "lens.spec",
     "lens.io", "lens.run", "lens", "lens.command", "validation.constrained", "validation.closed_forms",
     "validation.linear", "validation.dispersion", "validation.checks", "validation.figures", "validation", "plot",
     "init_spec", ""},
    {"cli", "__main__"},
]
LAYER = {m: i for i, layer in enumerate(LAYERS) for m in layer}


def _modules() -> dict[str, Path]:
    mods = {}
    for p in (ROOT / PKG).rglob("*.py"):
        parts = list(p.relative_to(ROOT / PKG).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = p
    return mods


def _imports(name: str, path: Path, mods) -> set[str]:
    tree = ast.parse(path.read_text())
    base = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    base = [b for b in base if b]
    out = set()
    for n in ast.walk(tree):
        if isinstance(n, ast.ImportFrom):
            if n.level:
                stem = base[: len(base) - (n.level - 1)] + ([n.module] if n.module else [])
            elif (n.module or "").split(".")[0] == PKG:
                stem = n.module.split(".")[1:]
            else:
                continue
            for a in n.names:
                sub = ".".join(stem + [a.name])
                out.add(sub if sub in mods else ".".join(stem))
        elif isinstance(n, ast.Import):
            for a in n.names:
                if a.name.split(".")[0] == PKG:
                    out.add(".".join(a.name.split(".")[1:]))
    return {m for m in out if m in mods and m != name}


def import_graph() -> dict[str, set[str]]:
    mods = _modules()
    return {m: _imports(m, p, mods) for m, p in mods.items()}


def longest_chain(graph) -> list[str]:
    """Longest import path between importable modules (``__main__``, the ``python -m`` shim that
    nothing imports, is left out; it would add one)."""
    def longest(m, seen=()):  # simple paths only, so a cycle (its own test fails) cannot recurse forever
        best = [m]
        for d in graph[m]:
            if d not in seen:
                tail = longest(d, seen + (m,))
                if len(tail) + 1 > len(best):
                    best = [m] + tail
        return best

    return max((longest(m) for m in graph if m != '__main__'), key=len)


def test_every_module_has_a_layer():
    assert set(import_graph()) - set(LAYER) == set()


def test_no_upward_imports_and_no_cycles():
    g = import_graph()
    upward = [(m, d) for m, deps in g.items() for d in deps if LAYER[d] > LAYER[m]]
    assert not upward, f"upward imports: {upward}"
    # within a layer: acyclic (a DFS that finds a back edge names the cycle)
    state = {}

    def visit(m, stack):
        state[m] = 1
        for d in g[m]:
            if state.get(d) == 1:
                raise AssertionError("import cycle: " + " -> ".join(stack[stack.index(d):] + [d]))
            if d not in state:
                visit(d, stack + [d])
        state[m] = 2

    for m in g:
        if m not in state:
            visit(m, [m])


def test_import_chains_are_short():
    chain = longest_chain(import_graph())
    assert len(chain) <= MAX_CHAIN, f"{len(chain)} modules: " + " -> ".join(c or PKG for c in chain)


def test_contract_checker_sees_real_edges():
    g = import_graph()
    assert "integrate" in g["engine"] and "kernels.common" in g["kernels.fused"] and "policy.decide" in g["sweep.plan"]
    assert "sweep.spec" not in g["io"] and "io" in g["sweep.store"]
    assert "sweep.plan" in g["sweep.shard"]  # TYPE_CHECKING and function-level imports count too


def _imported_names(path: Path) -> set[str]:
    """Every module and name imported by a file, TYPE_CHECKING blocks and function bodies included."""
    names = set()
    for n in ast.walk(ast.parse(path.read_text())):
        if isinstance(n, ast.ImportFrom):
            names.add("." * n.level + (n.module or ""))
            names.update(a.name for a in n.names)
        elif isinstance(n, ast.Import):
            names.update(a.name for a in n.names)
    return names


def test_io_imports_no_sweep_type():
    """io lays out a sweep's datasets from a types.Layout value (``SweepSpec.layout()``): it imports no
    sweep module, not even under TYPE_CHECKING, so engine -> result -> io has no hidden way back up
    (issue 26)."""
    path = ROOT / PKG / "io.py"
    names = _imported_names(path)
    assert not [m for m in names if "sweep" in m.lstrip(".").split(".")], names
    assert "SweepSpec" not in path.read_text() and "TYPE_CHECKING" not in path.read_text()


def test_status_meanings_are_one_table():
    """The column status's meanings are one dict, types.STATUS_MEANINGS: no module builds another
    (settings and io each rebuilt it as STATUS_NAMES; io's STATUS_MEANINGS shadowed it; issue 26)."""
    defined = []
    for m, p in _modules().items():
        for n in ast.walk(ast.parse(p.read_text())):
            targets = n.targets if isinstance(n, ast.Assign) else [n.target] if isinstance(n, ast.AnnAssign) else []
            table = isinstance(getattr(n, "value", None), (ast.Dict, ast.DictComp))
            defined += [(m, t.id) for t in targets if isinstance(t, ast.Name) and t.id.startswith("STATUS_")
                        and (table or t.id in ("STATUS_NAMES", "STATUS_MEANINGS"))]
    assert defined == [("types", "STATUS_MEANINGS")], defined


@pytest.mark.parametrize("code", [
    "import warp_tensegrity",
    "from warp_tensegrity.sweep import parse_spec; parse_spec('[scene]\\nn_prisms = 4\\n[sweep]\\n"
    "grid = { v0 = [0.01] }\\n[run]\\nt_end = 0.01\\naccuracy = 1e-3\\n').run_settings()",
    "from warp_tensegrity.sweep import load_spec; load_spec('sweeps/paper_2017.toml')",
])
def test_reading_a_spec_does_not_import_warp(code):
    r = subprocess.run([sys.executable, "-c", code + "; import sys; print('warp' in sys.modules)"],
                       cwd=ROOT, capture_output=True, text=True, env={"PYTHONPATH": str(ROOT), "PATH": ""})
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"

