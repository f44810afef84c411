"""``python -m spgeo`` is the ``spgeo`` command."""
import sys

from .cli import main

sys.exit(main())
