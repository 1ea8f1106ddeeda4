"""Tests of strings_bench/reports/."""
