"""``python -m rollergear_ros`` = the ``rollergear`` command."""

import sys

from rollergear_ros.cli.main import main

sys.exit(main())
