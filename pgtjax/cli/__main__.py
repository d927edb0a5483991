"""``python3 -m pgtjax.cli ...``: the ``pgtjax`` command."""

import sys

from . import main

if __name__ == "__main__":
    sys.exit(main())
