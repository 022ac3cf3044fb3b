"""``python -m isp`` = the ``isp`` command."""

import sys

from isp.cli.main import main

sys.exit(main())
