"""The validation gallery: the engine, in fp64 on the CPU, against closed forms (``docs/validation.md``).

* ``bessel``: the linear rigid-base (RB) impact against the exact Bessel form (Schrödinger 1914);
* ``soliton``: the unstressed RB column's solitary wave against the cubic chain's (Nesterenko);
* ``dispersion``: Bloch bands of the periodic column, FB and RB, their RB long-wave limit against
  c0, and the simulated speed against the same measure on the Bessel form;
* ``fb_modal``: the flexible-base (FB) small impact against the modal sum of :mod:`.linear`.

``warp-tensegrity validate`` runs :func:`run_validation` and draws :mod:`.figures`;
``tests/validation/test_validation.py`` runs each check.
"""

from __future__ import annotations

from .checks import Check, CheckGroup, check_bessel, check_dispersion, check_fb_modal, check_soliton

__all__ = ["CHECKS", "Check", "CheckGroup", "run_validation", "report"]

CHECKS = {"bessel": check_bessel, "soliton": check_soliton, "dispersion": check_dispersion, "fb_modal": check_fb_modal}
"""Every check group by name, in gallery order."""


def run_validation(names=None, device: str = "cpu") -> list[CheckGroup]:
    """Run the check groups ``names`` (default: all of :data:`CHECKS`) on ``device``. Their figures:
    :func:`warp_tensegrity.validation.figures.write_figures`."""
    names = list(CHECKS) if names is None else list(names)
    unknown = [n for n in names if n not in CHECKS]
    if unknown:
        raise ValueError(f"unknown validation checks {unknown}: choose among {', '.join(CHECKS)}")
    return [CHECKS[n](device=device) for n in names]


def report(groups) -> str:
    """A plain-text table: every check, its number, closed form, error and tolerance, and the notes."""
    lines = [f"{'check':<26} {'engine':>13} {'closed form':>13} {'error':>10} {'tolerance':>10}  result"]
    for g in groups:
        for c in g.checks:
            lines.append(f"{c.name:<26} {c.value:>13.7g} {c.reference:>13.7g} {c.error:>10.2e} {c.tolerance:>10.0e}  "
                         f"{'pass' if c.passed else 'FAIL'}")
    for g in groups:
        lines.append(f"\n{g.title}:")
        lines += [f"  - {n}" for n in g.notes]
    return "\n".join(lines)
