"""The Integrator: one batch's model, data and record arrays on one Warp device, advanced by the
Step of its launch path (:mod:`.step`: staged, block or lanes, all through one interface), with the
step counter, the record kernels and CUDA graph capture done once for every Step. What to integrate
with (method, dt, path) is decided by the policy (:mod:`warp_tensegrity.policy.decide`); the
methods are the staged Step's (:mod:`.staged.step`)."""

from __future__ import annotations

import contextlib
import gc
import time
from collections import deque
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from .block import step as _block  # noqa: F401 (registers the block Steps)
from .lanes import step as _lanes  # noqa: F401 (registers the lane Step)
from .model import REAL, Data, Model, build_model, make_data
from .staged.kernels import make_kernels
from .staged.step import Launcher, StagedStep  # noqa: F401 (registers the staged Step)
from .step import STEPS, Step
from ..runtime import drive, resolve_device
from ..options import RunSettings, SettingsError
from ..types import Path, Precision

if TYPE_CHECKING:
    from ..scene.batch import NetworkBatch

IDLE_POLL_S = 1e-3
"""Seconds between polls of the runs' events when every run stepping at once waits on the device
(the sleep leaves the GIL to the store's writer thread)."""
MAX_GRAPH_STEPS = 2000  # longest output interval (in steps) captured as one graph when launches end on outputs


@contextlib.contextmanager
def _gc_paused():
    """No garbage collection while a graph is captured: a collection inside the capture can free a
    Warp array, module or graph and record its destructor into the graph (warp #1714, #401; Newton
    and mjlab #821 suspend the collector the same way). It replaces a gc.collect() before each capture,
    which cost 0.12-0.18 s per run in a sweep's process (200,000 objects; 6 runs in phase_large's shard)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


class Integrator:
    """Holds the model, data and record arrays of one batch and advances it on one Warp device with
    the Step of its launch path (:data:`warp_tensegrity.sim.step.STEPS`)."""

    def __init__(self, batch: NetworkBatch, settings: RunSettings, dt: float, output_every: int, n_out: int, *,
                 path: Path, energy_parts: tuple[int, int] | None = None):
        """``path``: the launch path, whose registered Step runs the batch
        (:func:`warp_tensegrity.policy.paths.choose_path` decides it). ``energy_parts``: (below_node,
        end_node) of the energy-parts record (:func:`warp_tensegrity.measure.energy.part_nodes`), None:
        not recorded."""
        if settings.precision == Precision.AUTO:  # a batch stepped directly: no twin to verify fp32 (policy.groups)
            settings = replace(settings, precision=Precision.FP64)
        self.settings = settings
        self.path = Path(path)
        self.device = resolve_device(settings.device)
        step_cls: type[Step] = STEPS[self.path]
        why = step_cls.refusal(settings, batch, self.device)
        if why is not None:
            raise SettingsError(why)
        self.dt = dt
        self.every = output_every
        self.n_out = n_out
        t0 = time.perf_counter()
        with wp.ScopedDevice(self.device):
            self.model: Model = build_model(batch, settings.precision, self.device)
            m = self.model
            self.data: Data = make_data(m, batch.velocity, settings.method, not step_cls.staged_scratch,
                                        batch.initial_displacement)
            real = REAL[settings.precision]
            self.real = real
            self.k = make_kernels(real)  # the record kernels (every Step's, unless it records inside)
            self.launcher = Launcher(m, self.device, real, settings)
            self.launcher.column_kernels |= {self.k.record_energy.key, self.k.record_energy_parts.key}
            B = m.n_columns
            self.strain = None
            if settings.record_strain and m.n_prisms > 0:
                self.strain = wp.zeros((n_out, m.n_prisms, B), dtype=real)
            self.kinetic = wp.zeros((n_out, B), dtype=real)
            self.elastic = wp.zeros((n_out, B), dtype=real)
            self.energy_parts = energy_parts
            self.energy_below = self.energy_end = None
            if energy_parts is not None:  # the energy measures' record (measure.energy)
                self.energy_below = wp.zeros((n_out, B), dtype=real)
                self.energy_end = wp.zeros((n_out, B), dtype=real)
            self.stepper: Step = step_cls.create(self, batch)
        self.build_time = time.perf_counter() - t0
        self.graph = None
        self.graph_steps = 0
        self.steps_done = 0

    @property
    def contact(self):
        """The staged step's bar contact (scene contact = 'bars'), or None."""
        return getattr(self.stepper, "contact", None)

    @property
    def striker(self):
        """The staged step's striker (scene impact = 'striker'), or None."""
        return getattr(self.stepper, "striker", None)

    # ------------------------------------------------------------------ launch helpers
    def _launch(self, kernel, dim, inputs, model: str | None = None):
        """``model``: the argument group (types.ARGUMENT_GROUPS) whose Model arrays lead the inputs."""
        self.launcher.launch(kernel, dim, inputs, model)

    def _steps(self, n: int):
        """n steps as launches of at most steps_per_launch, each followed by the counter and the
        (step-gated) records, unless the step writes them itself (``records_inside``)."""
        st = self.stepper
        while n > 0:
            k = min(st.steps_per_launch, n)
            st.launch(self.data, self.settings, self.dt, k)
            st.advance_counter(self.data, k)
            if not st.records_inside:
                self._record()
            n -= k

    def _record(self):
        m, d = self.model, self.data
        if self.strain is not None:
            self._launch(self.k.record_strain, (m.n_prisms, m.n_columns),
                         [self.every, d.u, d.step, self.strain], model="strain")
        self._launch(self.k.record_energy, m.n_columns,
                     [self.every, d.u, d.v, d.step, self.kinetic, self.elastic], model="energy")
        if self.energy_parts is not None:
            self._launch(self.k.record_energy_parts, m.n_columns, [self.every, *self.energy_parts, d.u, d.v, d.step,
                                                                  self.energy_below, self.energy_end], model="energy")
        if m.n_prisms > 0:  # the feasibility record (types.FEASIBILITY_FLAGS), whether or not the strain is kept
            self._launch(self.k.record_feasibility, (m.n_prisms, m.n_columns), [self.every, d.u, d.status, d.step,
                         d.twist, d.twist_max, d.twist_min, d.height_min, d.left_slot], model="feasibility")
        elif m.n_pairs > 0:
            self._launch(self.k.record_pairs, (m.n_pairs, m.n_columns), [self.every, d.u, d.status, d.step,
                         d.pair_distance_min, d.cross_side, d.pair_left_slot], model="pairs")
        if self.striker is not None:
            self.striker.record(d, self.every)

    # ------------------------------------------------------------------ steps
    def load_kernels(self):
        """Compile/load the kernels this run uses now, with the block size they launch with, so no
        load happens while stepping or capturing."""
        records = ["record_energy", "record_pairs" if self.model.n_prisms == 0 else "record_feasibility"]
        if self.strain is not None:
            records.append("record_strain")
        if self.energy_parts is not None:
            records.append("record_energy_parts")
        for name in records:
            self.launcher.load(getattr(self.k, name))
        self.stepper.load_counter(self.device)
        self.stepper.load()

    def initialize(self):
        """Make the initial velocity exactly admissible, factor A(u0), compute a(u0), record step 0."""
        self.load_kernels()
        self.stepper.initialize(self.data, self.settings, self.dt)
        self._record()

    def step(self):
        """One step (eager launches)."""
        self.steps_done += 1
        self._steps(1)

    def advance(self, n: int):
        """Advance n steps. Launches end on output steps unless the Step's may end anywhere
        (``free_ends``: its records inside, or one step per launch); on CUDA whole periods (near
        steps_per_graph: a multiple of ``every``, or of the launch's steps) replay one captured graph."""
        st = self.stepper
        free = st.free_ends
        every = 1 if free else self.every  # launches may end anywhere, or on an output step
        unit = st.steps_per_launch if free else every
        period = self.graph_steps or unit * max(1, -(-int(self.settings.steps_per_graph) // unit))
        # a one-step-per-launch Step (staged) captures steps_per_graph steps whatever their number, as it always did
        graphable = self.device.is_cuda and (period <= MAX_GRAPH_STEPS or st.steps_per_launch == 1)
        while n > 0:
            phase = self.steps_done % every
            if graphable and phase == 0 and n >= period:
                if self.graph is None:
                    with _gc_paused(), wp.ScopedCapture(device=self.device) as cap:
                        for _ in range(period // unit):
                            self._steps(unit)  # launches end on every output step, or span them
                    self.graph = cap.graph
                    self.graph_steps = period
                wp.capture_launch(self.graph)
                k = period
            else:
                k = n if free else min(n, every - phase)
                self._steps(k)
            self.steps_done += k
            n -= k

    def run(self, n_steps: int, progress=None) -> tuple[float, float]:
        """Initialize, then advance ``n_steps`` in chunks (on CUDA ~20 per run, whole graphs each),
        calling ``progress(done, n_steps, n_failed)`` at most twice a second. Returns the seconds
        spent stepping and initializing (kernel loads included)."""
        return drive(self.run_steps(n_steps, progress))

    def run_steps(self, n_steps: int, progress=None):
        """:meth:`run` as a generator that yields while it steps, so that a driver can interleave several
        runs, each on its own CUDA stream (:func:`run_together`); it returns (stepping seconds,
        initialize seconds). On the CPU it yields None after each chunk. On CUDA it queues all its chunks
        in its first turn, so that the runs beside it build, and the host work between their turns runs,
        while the device steps; it then yields the CUDA event it waits for (a chunk's end, for the
        progress, else the run's end), and the driver resumes it once that is complete."""
        cuda = self.device.is_cuda
        with wp.ScopedDevice(self.device):
            t_compile = time.perf_counter()
            self.initialize()
            if not cuda:  # on CUDA the first chunk waits for it in stream order: no host wait
                self.synchronize()
            t_compile = time.perf_counter() - t_compile
        t0 = last = time.perf_counter()
        done = reported = 0
        # advance in chunks (on CUDA ~20 per run, whole graphs each); report at most twice a second
        chunk = int(self.settings.steps_per_graph)
        if cuda:
            chunk *= max(1, n_steps // (chunk * 20))
        # on CUDA each chunk is followed by a copy of the status into pinned memory and an event: the
        # progress reads the copy once the event is complete, never waiting for the work just launched
        watch = progress is not None and cuda
        queued: deque = deque()
        status = wp.empty(self.data.status.shape, dtype=self.data.status.dtype, device="cpu", pinned=True) if watch else None
        while done < n_steps:
            n = min(chunk, n_steps - done)
            with wp.ScopedDevice(self.device):
                self.advance(n)
                done += n
                if watch:
                    wp.copy(status, self.data.status)
                    queued.append((wp.record_event(), done))
                elif progress is not None and not cuda and (time.perf_counter() - last > 0.5 or done == n_steps):
                    self.synchronize()
                    progress(done, n_steps, self.n_failed())
                    reported, last = done, time.perf_counter()
            if not cuda and done < n_steps:
                yield None
        if cuda:
            with wp.ScopedDevice(self.device):
                end = wp.record_event()
            while queued:
                event, finished = queued.popleft()
                yield event
                if time.perf_counter() - last > 0.5 and queued:
                    # the copy may be a later chunk's by now: a count of failures no older than this chunk's
                    progress(finished, n_steps, int(np.count_nonzero(status.numpy())))
                    reported, last = finished, time.perf_counter()
            yield end
        with wp.ScopedDevice(self.device):
            self.synchronize()
            if progress is not None and reported < n_steps:
                progress(n_steps, n_steps, self.n_failed())
        return time.perf_counter() - t0, t_compile

    def synchronize(self):
        """Wait for this run's work: its device's current stream (the run's own when interleaved)."""
        if self.device.is_cuda:
            wp.synchronize_stream(wp.get_stream(self.device))
        else:
            wp.synchronize_device(self.device)

    # ------------------------------------------------------------------ results
    def n_failed(self) -> int:
        return int(np.count_nonzero(self.data.status.numpy()))


def run_together(gens: list, device, interleave: bool | None = None) -> list:
    """Drive several runs to their ends and return their values in order. On a CUDA device each run
    gets its own stream and they are resumed in turn, so that runs too narrow to fill the GPU (a
    sweep's groups of like stiffness and their error-estimate twins) step at once; the columns are
    independent, so each run's numbers are those it has alone. A run that yields a CUDA event is
    resumed once that is complete; when every live run waits on one (no host work is left), the
    driver polls them every :data:`IDLE_POLL_S`. Elsewhere one after another, as :func:`drive`
    would. ``interleave``: resume in turn (True; on the CPU without streams, for tests: not the lane
    step, whose CPU emulation is a process-wide setting) or one after another (False); None: on
    CUDA only."""
    device = resolve_device(device)
    if interleave is None:
        interleave = device.is_cuda
    if not interleave or len(gens) < 2:
        return [drive(g) for g in gens]
    streams = [wp.Stream(device) if device.is_cuda else None for _ in gens]
    out: list = [None] * len(gens)
    live = list(range(len(gens)))
    waits: dict = {}  # run -> the event it waits for
    while live:
        ready = [i for i in live if i not in waits or waits[i].is_complete]
        if not ready:  # every live run waits on the device: poll, so whichever ends first goes on first
            time.sleep(IDLE_POLL_S)
            continue
        for i in ready:
            with wp.ScopedStream(streams[i], sync_enter=False):  # None (the CPU): no stream to set
                try:
                    got = next(gens[i])
                except StopIteration as stop:
                    out[i] = stop.value
                    live.remove(i)
                    waits.pop(i, None)
                    continue
            if got is None:
                waits.pop(i, None)
            else:
                waits[i] = got
    return out
