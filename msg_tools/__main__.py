"""``python -m msg_tools``: same as the ``msg-tools`` command."""

import sys

from .cli import main

sys.exit(main())
