"""The price of a shard's runs stepped at once on a GPU (policy.calibrate.together_seconds): no less
than the longest run, no less than the slot-seconds over the device's capacity; the sum elsewhere."""

from __future__ import annotations

import pytest

from warp_tensegrity.policy.calibrate import together_seconds


def test_runs_together_cost_the_larger_of_the_longest_and_the_shared_slots():
    runs = [(5.0, 512), (3.0, 768), (1.0, 256)]  # phase_large's three groups, their seconds alone
    assert together_seconds(runs, None) == pytest.approx(9.0)  # the CPU: one after another
    assert together_seconds(runs, 1056) == pytest.approx(5.0)  # room for all: the longest
    # a small device: slot-seconds (5x512 + 3x768 + 1x256 = 5,120) over 512 slots, each run at most 512
    assert together_seconds(runs, 512) == pytest.approx((5 * 512 + 3 * 512 + 1 * 256) / 512)
    assert together_seconds([(2.0, 4096)], 1056) == pytest.approx(2.0)  # one run: its own price
