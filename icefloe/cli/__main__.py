"""``python -m icefloe.cli``: the same as the `icefloe` command."""

import sys

from . import main

sys.exit(main())
