"""`python -m strings_bench ...` = the `strings-bench` command (for checkouts that are not pip-installed)."""

import sys

from strings_bench.cli import main

sys.exit(main())
