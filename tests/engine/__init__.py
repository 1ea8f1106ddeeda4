"""Tests of strings_bench/engine/."""
