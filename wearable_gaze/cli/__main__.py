"""``python -m wearable_gaze.cli``: the same as the ``wearable-gaze`` command."""

import sys

from . import main

sys.exit(main())
