"""A graph capture runs with the garbage collector paused (sim.integrate._gc_paused): no collection can
free a Warp object into the graph, and the collector's state is given back, also on an error."""

import gc

import pytest

from warp_tensegrity.sim.integrate import _gc_paused


def test_the_collector_is_off_inside_and_restored_after():
    assert gc.isenabled()
    with _gc_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(RuntimeError), _gc_paused():
        raise RuntimeError("a capture that fails")
    assert gc.isenabled()


def test_a_collector_already_off_stays_off():
    gc.disable()
    try:
        with _gc_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()
    finally:
        gc.enable()
