"""Tests of strings_bench/eval/."""
