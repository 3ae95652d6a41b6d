"""The block step family ("fused" path): RATTLE as one kernel, a thread block per column."""
