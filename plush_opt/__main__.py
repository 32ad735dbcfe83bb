"""``python -m plush_opt``: the same as the ``plush-opt`` command."""

import sys

from plush_opt.apps.cli import main

sys.exit(main())
