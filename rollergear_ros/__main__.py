"""``python -m rollergear_ros`` = the ``rollergear`` command."""

import sys

from rollergear_ros.cli import main

sys.exit(main())
