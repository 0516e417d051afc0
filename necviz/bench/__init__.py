"""Benchmarks behind ``necviz bench``: each prints a table and can write JSON."""
