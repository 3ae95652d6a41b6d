"""The validation gallery: the engine, in fp64 on the CPU, against closed forms (``docs/validation.md``).

* ``bessel``: the linear rigid-base (RB) impact against the exact Bessel form (Schrödinger 1914);
* ``soliton``: the unstressed RB column's solitary wave against the cubic chain's (Nesterenko);
* ``dispersion``: the simulated RB and FB columns' mode frequencies against the Bloch bands of the
  periodic column; the RB band and its long-wave limit against c0 (a check of the reference only);
  the simulated speed against the same measure on the Bessel form;
* ``fb_modal``: the flexible-base (FB) small impact, under two impacts, against the modal sum of
  :mod:`.linear` on the column rebuilt from the closed forms (:mod:`.reference_column`);
* ``interface``: a long-wave pulse across the joint of two RB segments of different prestrain against
  the discrete chain's impedances (:mod:`.interface`);
* ``diatomic``: an RB column of level masses m | 2m driven by wave packets inside and outside its band gap
  against its two-level Bloch cell and complex Bloch wavenumber (:mod:`.diatomic`);
* ``preload``: the RB column under an end preload F0: its static height and twist against the
  prism's force-displacement law along the mechanism path, and a small impact on it against the
  chain of its tangent stiffness (:mod:`.preload`).

Every check runs the engine except those marked ``engine=False`` (checks of the reference only; the
report says so). ``warp-tensegrity validate`` runs :func:`run_validation` and draws :mod:`.figures`;
``tests/validation/test_validation.py`` runs each check, ``tests/validation/test_perturbation.py``
shows that an engine with a constant 5 % off fails some check.
"""

from __future__ import annotations

import importlib

__all__ = ["CHECKS", "Check", "CheckGroup", "run_validation", "report"]

_CHECKS = {"bessel": "checks", "soliton": "checks", "dispersion": "checks", "fb_modal": "checks",
           "interface": "interface", "diatomic": "diatomic", "striker": "checks", "preload": "checks"}
"""Every check group by name, in gallery order, and the module of its ``check_<name>``: loaded on
first use (the checks import SciPy; `warp-tensegrity run` imports this package and needs none)."""


def __getattr__(name):
    if name == "CHECKS":  # {name: check function}, every check group in gallery order
        return {n: getattr(importlib.import_module(f".{m}", __name__), f"check_{n}") for n, m in _CHECKS.items()}
    if name in ("Check", "CheckGroup"):
        return getattr(importlib.import_module(".checks", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def run_validation(names=None, device: str = "cpu") -> list[CheckGroup]:
    """Run the check groups ``names`` (default: all of :data:`CHECKS`) on ``device``. Their figures:
    :func:`warp_tensegrity.validation.figures.write_figures`."""
    checks = __getattr__("CHECKS")
    names = list(checks) if names is None else list(names)
    unknown = [n for n in names if n not in checks]
    if unknown:
        raise ValueError(f"unknown validation checks {unknown}: choose among {', '.join(checks)}")
    return [checks[n](device=device) for n in names]


def report(groups) -> str:
    """A plain-text table: every check, its number, closed form, error and tolerance, whether it runs the
    engine ('reference only' where it checks the reference alone), and the notes."""
    lines = [f"{'check':<26} {'engine':>13} {'closed form':>13} {'error':>10} {'tolerance':>10}  result  runs"]
    for g in groups:
        for c in g.checks:
            lines.append(f"{c.name:<26} {c.value:>13.7g} {c.reference:>13.7g} {c.error:>10.2e} {c.tolerance:>10.0e}  "
                         f"{'pass' if c.passed else 'FAIL'}    {'engine' if c.engine else 'reference only'}")
    for g in groups:
        lines.append(f"\n{g.title}:")
        lines += [f"  - {n}" for n in g.notes]
    return "\n".join(lines)
