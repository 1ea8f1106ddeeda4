"""Tests of strings_bench/raster/."""
