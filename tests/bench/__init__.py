"""Tests of strings_bench/bench/."""
