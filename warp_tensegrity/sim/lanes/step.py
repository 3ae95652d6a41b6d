"""The lane Step: RATTLE with one warp per column (:class:`.lanes.LaneStep`, its kernel and lane
arrays), behind the one Step interface; its launches write the output records themselves."""

from __future__ import annotations

import warp as wp

from ...policy.lane_fit import lane_support
from ...types import Method, Path
from ..step import Step, register
from .lanes import LaneStep


@register
class LanesStep(LaneStep, Step):
    """:class:`.lanes.LaneStep` as a Step (the counter is the Step's one kernel)."""

    path = Path.LANES

    @classmethod
    def refusal(cls, settings, batch, device) -> str | None:
        if settings.method != Method.RATTLE:
            return f"the fused path needs method = 'rattle' (got method = {settings.method!r})"
        if not (device.is_cuda or wp.config.enable_cpu_blocks):  # each lane would be a block of its own
            return ("the lane step on the CPU needs Warp's CPU blocks (wp.config.enable_cpu_blocks; "
                    "engine runs switch them on: paths.lane_emulation)")
        why = lane_support(batch)
        if why is not None:
            return f"the warp-per-column step does not take this batch: {why}"
        return super().refusal(settings, batch, device)

    @classmethod
    def create(cls, integ, batch) -> LanesStep:
        return cls(integ.model, batch, integ.device, integ.every, integ.strain, integ.kinetic, integ.elastic,
                   integ.energy_parts, integ.energy_below, integ.energy_end)

    def initialize(self, data, settings, dt: float):
        LaneStep.launch(self, data, settings, dt, 0, init=1)

    def launch(self, data, settings, dt: float, n_sub: int, init: int = 0):
        LaneStep.launch(self, data, settings, dt, n_sub, init)

