"""The layout and docs rules, one lint step (test_rules.py)."""
