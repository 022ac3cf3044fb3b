"""``python -m isp`` = the ``isp`` command."""

import sys

from .cli import main

sys.exit(main())
