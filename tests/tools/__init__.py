"""Tests of the scripts users and maintainers rerun (benchmarks/, scripts/)."""
