"""The one Step interface: what the Integrator asks of every step family (staged, block, lanes), and
the registry of Steps by launch path (:class:`warp_tensegrity.types.Path`).

A Step advances one batch's :class:`~warp_tensegrity.sim.model.Data` by ``n`` steps per launch and
says whether its launches write the output records themselves (``records_inside``); the Integrator
(:mod:`.integrate`) does the rest the same way for every family: the step counter, the record
kernels after launches that do not, graph capture and the output alignment."""

from __future__ import annotations

import abc
from typing import TYPE_CHECKING, ClassVar

import warp as wp

from ..types import Path

if TYPE_CHECKING:
    from ..options import RunSettings
    from ..scene.batch import NetworkBatch


@wp.kernel(enable_backward=False)
def advance_counter_by(step: wp.array(dtype=int), n: int):
    """The step counter, after ``n`` steps (every family's, one kernel)."""
    step[0] = step[0] + n


class Step(abc.ABC):
    """One step family's device arrays and launches for one batch on one device."""

    path: ClassVar[Path]
    """The launch path this Step runs (its key in :data:`STEPS`)."""
    records_inside: ClassVar[bool] = False
    """True: the launches write the output records themselves (a launch may span many outputs); False:
    the Integrator launches its record kernels (gated by the step counter) after every launch."""
    steps_per_launch: int = 1
    """The most steps one :meth:`launch` takes."""
    staged_scratch: ClassVar[bool] = False
    """Whether the Data carries the staged kernels' scratch (u_prev, imp, band, lam: ``make_data``)."""

    @classmethod
    def refusal(cls, settings: RunSettings, batch: NetworkBatch, device) -> str | None:
        """Why this Step cannot run ``batch`` with ``settings`` on ``device`` (a sentence naming the
        setting and its value), or None: it can. The families' own reasons follow the common ones."""
        if batch.contact_pairs is not None and cls.path != Path.STAGED:
            return (f"bar contact runs on the staged path with method = 'rattle' (got path {cls.path.value}, "
                    f"method {settings.method!r})")
        if batch.striker_mass is not None and cls.path != Path.STAGED:
            return (f"the striker runs on the staged path with method = 'rattle' (got path {cls.path.value}, "
                    f"method {settings.method!r})")
        return None

    @classmethod
    @abc.abstractmethod
    def create(cls, integ, batch: NetworkBatch) -> Step:
        """The Step for the Integrator ``integ`` (its model, data, device, settings and record arrays)."""

    @property
    @abc.abstractmethod
    def description(self) -> str:
        """The path in words, for a run's diagnostics."""

    @abc.abstractmethod
    def load(self) -> None:
        """Compile/load this Step's kernels, with the block size they launch with."""

    @abc.abstractmethod
    def initialize(self, data, settings: RunSettings, dt: float) -> None:
        """Make the initial velocity admissible and compute a(u0) (no step taken)."""

    @abc.abstractmethod
    def launch(self, data, settings: RunSettings, dt: float, n_sub: int) -> None:
        """``n_sub`` (at most :attr:`steps_per_launch`) steps of size ``dt`` (s)."""

    @property
    def free_ends(self) -> bool:
        """Whether a launch may end on any step (its records inside, or one step per launch: the
        gated record kernels then see every step), not only on output steps."""
        return self.records_inside or self.steps_per_launch == 1

    def load_counter(self, device) -> None:
        advance_counter_by.module.load(device, 1)

    def advance_counter(self, data, n: int) -> None:
        """The step counter ``data.step``, after ``n`` steps."""
        wp.launch(advance_counter_by, dim=1, inputs=[data.step, int(n)], device=data.step.device, block_dim=1)


STEPS: dict[Path, type[Step]] = {}
"""Every registered Step, by the launch path it runs (:func:`register`)."""


def register(cls: type[Step]) -> type[Step]:
    """Class decorator: ``cls`` runs the launch path ``cls.path`` (one Step a path)."""
    if cls.path in STEPS and STEPS[cls.path] is not cls:
        raise ValueError(f"two Steps for path {cls.path.value!r}: {STEPS[cls.path].__name__} and {cls.__name__}")
    STEPS[cls.path] = cls
    return cls
