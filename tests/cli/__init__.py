"""Tests of strings_bench/cli/."""
