"""The validation gallery's results: one number against its reference (:class:`Check`) and the checks of one
reference with the arrays of its figure (:class:`CheckGroup`). A leaf: the check modules
(:mod:`.checks`, :mod:`.interface`, :mod:`.diatomic`) import it without importing each other."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Check", "CheckGroup"]


@dataclass
class Check:
    """One number against its closed form."""

    name: str
    what: str
    value: float
    """The engine's number (in a check of the reference only, the reference's)."""
    reference: float
    """The closed form's number."""
    error: float
    """The compared error (relative, as ``what`` says)."""
    tolerance: float
    engine: bool = True
    """False for a check of the reference only (no engine run enters it): it cannot catch an engine error."""

    @property
    def passed(self) -> bool:
        return bool(np.isfinite(self.error) and self.error <= self.tolerance)


@dataclass
class CheckGroup:
    """The checks of one closed form, with the arrays of its figure."""

    name: str
    title: str
    checks: list[Check]
    data: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)
