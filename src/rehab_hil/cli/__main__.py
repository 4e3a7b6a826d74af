"""``python -m rehab_hil.cli``: the same as the ``rehab-hil`` console script."""

import sys

from rehab_hil.cli import main

sys.exit(main())
