"""Tests of the documentation: its pages, tables, API reference, cookbook and site."""
