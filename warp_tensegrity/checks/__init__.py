"""Independent float64 NumPy checks of the engine, used by tests and analysis, never by the engine:
:mod:`.reference` (Lagrange-multiplier and the paper's matrix-form integrators) and :mod:`.linear`
(linearised modes, stiffness, long-wave speed). They may import :mod:`warp_tensegrity.scene` only,
so they stay independent of the Warp code they check."""
