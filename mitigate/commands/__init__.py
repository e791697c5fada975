"""Sub-commands of the ``mitigate`` CLI, one module each."""
