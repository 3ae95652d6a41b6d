"""The lane step family: RATTLE with one warp per column, its state in registers."""
