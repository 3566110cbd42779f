"""``python -m dtid.cli``: the ``dtid`` command."""

import sys

from dtid.cli import main

sys.exit(main())
