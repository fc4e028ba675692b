"""``python -m roadtrack.testbed.cli``: the ``testbed`` command."""
import sys

from .main import main

sys.exit(main())
