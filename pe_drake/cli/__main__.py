"""``python -m pe_drake.cli <command> ...``: the ``pe-drake`` console script, for a checkout that
is not pip-installed."""

import sys

from pe_drake.cli import main

sys.exit(main())
