"""Tests of strings_bench/methods/."""
