"""Tests of strings_bench/store/."""
