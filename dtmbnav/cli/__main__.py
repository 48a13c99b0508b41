"""``python -m dtmbnav.cli``: the ``dtmbnav`` command line, as the console script runs it."""

import sys

from dtmbnav.cli import main

sys.exit(main())
