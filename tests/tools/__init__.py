"""Tests of the scripts users and maintainers rerun (tools/, studies/, scripts/)."""
