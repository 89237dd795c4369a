"""``python -m pe_drake.cli <command> ...``: the same as the ``pe-drake`` console script.

For a checkout that is on ``PYTHONPATH`` but not pip-installed (no ``pe-drake`` on ``PATH``).
"""

import sys

from pe_drake.cli import main

sys.exit(main())
