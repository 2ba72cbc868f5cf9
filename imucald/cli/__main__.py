"""``python -m imucald.cli``: the same as the ``imucald`` console script."""
from . import entry

entry()
