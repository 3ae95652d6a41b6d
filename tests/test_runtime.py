"""runtime: the CUDA driver version as recorded in every output's provenance."""

from warp_tensegrity.runtime import _driver_text


def test_driver_text_accepts_warp_tuple_and_int_forms():
    # Warp 1.19 returns (major, minor); older releases returned 1000*major + 10*minor
    assert _driver_text((13, 0)) == "13.0"
    assert _driver_text((12, 8)) == "12.8"
    assert _driver_text(12080) == "12.8"
    assert _driver_text(None) == "none"
