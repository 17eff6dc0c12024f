"""``python -m jaxrt``: the ``jaxrt`` command (:mod:`jaxrt.cli.command`)."""

import sys

from jaxrt.cli.command import main

sys.exit(main())
