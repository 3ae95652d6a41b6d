"""A test helper: the process's address space capped, so that an allocation that escapes a size
check fails its test (MemoryError) instead of taking the machine (issue 30: the unfixed code grew
to 24 GB). Shared by tests/policy/test_sizes.py and tests/test_fuzz.py."""

import contextlib
import resource

import psutil


@contextlib.contextmanager
def address_space_cap(extra: float = 2e9):
    """Allocations beyond ``extra`` bytes more address space fail (MemoryError) inside."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = psutil.Process().memory_info().vms + int(extra)
    resource.setrlimit(resource.RLIMIT_AS, (cap if hard == resource.RLIM_INFINITY else min(cap, hard), hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
