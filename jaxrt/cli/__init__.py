"""The ``jaxrt`` command, its worker processes and Ctrl-C handling."""
