"""``python -m ilcpmac``: the ``ilcpmac`` command line."""

from ilcpmac.cli import entry_point

entry_point()
