"""``python -m cgvqm_core``: the ``cgvqm`` command line."""

import sys

from .cli import main

sys.exit(main())
