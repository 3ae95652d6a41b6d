"""Test and benchmark references that are not part of the installed package: ``reference.py``, the
independent fp64 simulator the engine is checked against. Import it as ``tests.references.reference``
with the repository root on ``sys.path`` (``python -m pytest`` and ``python -m benchmarks...`` from the
root put it there; pytest's ``pythonpath`` setting does too)."""
