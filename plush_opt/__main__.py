"""``python -m plush_opt``: the same as the ``plush-opt`` command."""

import sys

try:
    from plush_opt.apps.cli import main
except KeyboardInterrupt:        # Ctrl-C while the command line is imported: no traceback
    print("plush-opt: interrupted (SIGINT)", file=sys.stderr)
    sys.exit(130)

code = main()
# Under ``-m``, CPython exits by SIGINT (not with ``code``) when a Ctrl-C, even
# one main() caught, ended code run from a string (dataclasses build their
# methods so); a string evaluation resets that flag.
exec("None")   # noqa: S102 - a constant string
sys.exit(code)
