"""Tests of strings_bench/core/."""
