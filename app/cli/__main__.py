"""`python -m app.cli`: the `calib` command."""

import sys

from . import main

sys.exit(main())
