"""``python -m ocreach ...``: the same command line as the ``ocreach`` script (``ocreach.cli.main``)."""
import sys

from ocreach.cli import main

sys.exit(main())
