"""Tests of strings_bench/scene/."""
