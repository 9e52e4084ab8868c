"""``python -m wearable_gaze``: the same as the ``wearable-gaze`` command."""

import sys

from .cli import main

sys.exit(main())
