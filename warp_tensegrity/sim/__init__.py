"""The simulation layer: the device model, the step families and the Integrator that drives them.

* :mod:`.common`: the ``@wp.func`` bodies the step families share (cable law, per-column reads, Gram
  rows, impulses, status codes, the serial banded Cholesky), each written once;
* :mod:`.model`: the device model and data (the arrays the kernels read);
* :mod:`.staged`: one kernel per stage (per-node kernels; one thread per column for the constraint
  solves in :mod:`.staged.solver`); every method, and the staged-only bar contact
  (:mod:`.staged.contact`) and striker (:mod:`.staged.striker`);
* :mod:`.block`: RATTLE as one kernel, a thread block per column (the "fused" path), its in-block
  pieces in :mod:`.block.coop`;
* :mod:`.lanes`: RATTLE with one warp per column (state in registers), its pieces in
  :mod:`.lanes.lane_funcs`, :mod:`.lanes.lane_rigid` and :mod:`.lanes.lane_ops`;
* :mod:`.integrate`: the Integrator, which drives a step family's Step through one interface.

Nothing here imports a higher layer (measure, run, applications); tests/test_layout.py checks it.
"""
