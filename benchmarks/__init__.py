"""Benchmarks of the warp_tensegrity engine: throughput, roofline, peers (see benchmarks/README.md)."""
