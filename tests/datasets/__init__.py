"""Tests of strings_bench/datasets/."""
