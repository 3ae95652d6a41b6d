"""The run decided once: :func:`.decide.decide` -> :class:`.decide.RunPlan` (method, precision, dt,
truncation, path; :mod:`.accuracy`, :mod:`.paths`, :mod:`.lane_fit`), the one cost model
(:mod:`.cost`) and its calibration probe (:mod:`.calibrate`). NumPy only at import: Warp loads
when a device is resolved or a probe runs. The public names are the package's
(``warp_tensegrity.decide``, ``RunPlan``, ``estimate_batch``)."""
