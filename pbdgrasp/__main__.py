"""``python -m pbdgrasp``: the ``pbdgrasp`` command line."""

import sys

from pbdgrasp.cli import main

sys.exit(main())
