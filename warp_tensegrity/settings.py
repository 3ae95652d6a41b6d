"""Run settings: what goes into a run (host side). Every run option is declared once, in
:mod:`warp_tensegrity.options` (re-exported here). What comes out: :mod:`.result`."""

from __future__ import annotations

from .options import COLUMN_PARAMETERS, METHODS, PRECISIONS, RunSettings, SettingsError  # noqa: F401 (re-exported)
from .types import STATUS_MEANINGS, TIME  # noqa: F401 (re-exported)
