"""Benchmarks: speed, memory and quality of every part, written to docs/benchmarks.md."""
