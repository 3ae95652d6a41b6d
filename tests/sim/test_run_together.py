"""Runs stepped at once (issue 33 item 5: a sweep's groups and twins fill the GPU together): the
generators the engine steps with, resumed in turn (on CUDA each on its own stream; on the CPU
interleaved without streams), give every run exactly the numbers it gets alone."""

from __future__ import annotations

import contextlib

import numpy as np

from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch
from warp_tensegrity.engine import run_batches
from warp_tensegrity.policy.decide import decide
from warp_tensegrity.runtime import drive
from warp_tensegrity.sim.integrate import run_together

CONFIG = ColumnConfig(n_prisms=7)
# a flexible-base and a rigid-base batch at their own dt and lengths (a sweep's groups), fused path
RUNS = [({"prestrain": [0.0, 0.002], "v0": [0.05, 0.1], "base_rigidity": [0.0, 0.5]}, 2e-4, 0.03),
        ({"prestrain": [0.002, 0.004, 0.001], "v0": [0.08, 0.02, 0.1], "base_rigidity": [1.0, 1.0, 1.0]}, 5e-4, 0.05)]
KEYS = ("kinetic_energy", "elastic_energy", "final_displacement", "final_velocity", "bar_length_error", "status")


def _plans(device):
    return [decide(CONFIG, p, RunSettings(device=device, precision="fp64", method="rattle", dt=dt, t_end=t_end,
                                          output_interval=t_end / 10, fused=True))
            for p, dt, t_end in RUNS]


def test_runs_stepped_together_get_the_numbers_they_get_alone(device):
    plans = _plans(device)
    alone = [simulate_batch(CONFIG, p, plan=rp) for (p, _, _), rp in zip(RUNS, plans)]
    seen = [[] for _ in RUNS]
    cbs = [lambda d, n, f, i=i: seen[i].append((d, n, f)) for i in range(len(RUNS))]
    together, stages = run_batches([(CONFIG, p, rp) for (p, _, _), rp in zip(RUNS, plans)], device, cbs,
                                   interleave=True)
    assert [r.n_steps for r in together] == [rp.n_steps for rp in plans] and plans[0].n_steps != plans[1].n_steps
    for a, b in zip(alone, together):
        for k in KEYS:
            np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    # each run's progress reaches its own end; the set's stages are all there and stepping is not negative
    assert all(s[-1][0] == s[-1][1] == rp.n_steps for s, rp in zip(seen, plans))
    assert set(stages) == {"build", "compile", "stepping", "measurement", "transfer"} and stages["stepping"] >= 0


def test_interleaved_generators_resume_in_turn_and_return_in_order(device):
    order = []

    def gen(name, n):
        for k in range(n):
            order.append((name, k))
            yield
        return name

    assert run_together([gen("a", 3), gen("b", 1), gen("c", 2)], "cpu", interleave=True) == ["a", "b", "c"]
    assert order[:3] == [("a", 0), ("b", 0), ("c", 0)]  # in turn, not one after another
    order.clear()
    assert run_together([gen("a", 2), gen("b", 1)], "cpu", interleave=False) == ["a", "b"]
    assert order == [("a", 0), ("a", 1), ("b", 0)]
    assert drive(gen("d", 2)) == "d"


def test_host_work_steps_with_the_runs_and_counts_in_its_stage(device):
    """The base-mode analysis of a GPU sweep steps with the runs (sweep.shard): one distinct pair per
    turn, the same ratios as computed alone, its seconds in 'measurement'."""
    from warp_tensegrity.engine import HostWork
    from warp_tensegrity.scene.base_modes import base_mode_ratios, base_mode_ratios_steps

    params = {"prestrain": np.array([0.0, 0.002, 0.002, 0.004]), "base_rigidity": np.array([0.0, 0.5, 0.5, 1.0])}
    turns = []
    gen = base_mode_ratios_steps(CONFIG, params, 4)

    def counted():
        turns.append(len(turns))
        return contextlib.nullcontext()

    work = HostWork(gen, "measurement", counted)
    plans = _plans(device)
    _, stages = run_batches([(CONFIG, p, rp) for (p, _, _), rp in zip(RUNS, plans)], device, interleave=True,
                            host=[work])
    alone = base_mode_ratios(CONFIG, params, 4)
    np.testing.assert_array_equal(work.value, alone)
    assert np.isnan(alone[3]) and np.all(np.isfinite(alone[:3]))  # rigid bases have no base modes
    assert len(turns) == 3  # two distinct flexible pairs: a turn each, and the one that returns
    assert stages["measurement"] >= work.seconds > 0


class _Event:
    """A stand-in for a CUDA event: complete after ``polls`` queries (or once waited on)."""

    def __init__(self, name, polls):
        self.name, self.polls, self.waited = name, polls, False

    @property
    def is_complete(self):
        self.polls -= 1
        return self.waited or self.polls < 0


def test_a_run_waiting_on_its_event_is_resumed_once_it_is_complete(monkeypatch):
    """A CUDA run queues its chunks and then yields the event it waits for: the driver resumes the
    others (and the host work) meanwhile, resumes it only once the event is complete, and polls (a
    short sleep) only when every live run waits and no host work is left."""
    from warp_tensegrity.sim import integrate

    sleeps = []
    monkeypatch.setattr(integrate.time, "sleep", lambda s: sleeps.append(s))
    order = []

    def run(name, polls):
        order.append((name, "queued"))
        ev = _Event(name, polls)
        yield ev
        assert ev.is_complete, f"{name} resumed before its event was complete"
        order.append((name, "done"))
        return name

    def host(n):
        for k in range(n):
            order.append(("host", k))
            yield None
        return "host"

    assert run_together([run("a", 2), run("b", 20), host(3)], "cpu", interleave=True) == ["a", "b", "host"]
    assert order[:3] == [("a", "queued"), ("b", "queued"), ("host", 0)]
    # a completes after its polls while the host work steps; the driver sleeps only once b alone waits
    assert order.index(("a", "done")) < order.index(("b", "done"))
    assert order.index(("host", 2)) < order.index(("b", "done"))
    assert sleeps and all(s == integrate.IDLE_POLL_S for s in sleeps)
    assert len(sleeps) < 20  # b: 20 polls in all, some of them in the turns of a and the host work


def test_drive_waits_on_the_events_a_run_yields(monkeypatch):
    from warp_tensegrity import runtime

    import warp as wp

    waited = []
    monkeypatch.setattr(wp, "synchronize_event", lambda ev: waited.append(ev.name))

    def run():
        yield None
        yield _Event("end", 10)
        return "ok"

    assert runtime.drive(run()) == "ok" and waited == ["end"]
