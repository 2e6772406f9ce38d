"""Real-data command groups of the CLI (``distnav uwb ...``, ``distnav gnss ...``)."""
