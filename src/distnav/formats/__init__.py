"""File formats: readers and writers, nothing else (above models, below commands and experiments)."""
