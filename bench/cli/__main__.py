"""``python -m gridflow.bench.cli``: the command line (:func:`gridflow.bench.cli.main`)."""

import sys

from . import main

sys.exit(main())
