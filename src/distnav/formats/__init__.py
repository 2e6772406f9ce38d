"""File formats: readers and writers, above the models (a reader may build a model's object from a file) and below
the commands and experiments that call them.

The layers below — network, exchange, algorithms, models — write no files (``tests/test_layers.py`` checks it);
writers live here (or return the text, ``format_…``, for :func:`distnav.output.atomic_write_text`). One reader stays
below on purpose: :func:`distnav.network.partition.read_partition`, which every MPI rank calls at start-up inside
the exchange, before any model exists (it only reads).
"""
