"""``python -m imucald.cli``: the same as the ``imucald`` console script."""
import sys

from . import main

sys.exit(main())
