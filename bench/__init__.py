"""Benchmarks: scripts that print markdown tables and write PNG plots to out/bench/."""
