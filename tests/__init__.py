"""The test suite, one folder per layer of strings_bench/ (see conftest.py)."""
