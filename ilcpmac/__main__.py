"""``python -m ilcpmac``: the ``ilcpmac`` command line."""

from ilcpmac.cli import main

main(prog_name="ilcpmac")
