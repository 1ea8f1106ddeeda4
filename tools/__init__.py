"""Tools that users and maintainers rerun: timings against a reference measured in the same run, banking a run's
cells, fingerprints of a training (tools/README.md lists them). Each runs as `python -m tools.NAME` from the
repository's root or as `python tools/NAME.py`, and uses only public names of the installed package."""
