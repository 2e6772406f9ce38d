"""File formats: readers and writers of the files distnav reads and writes (RINEX, SP3, Bias-SINEX, IONEX, ...).

Above the models (a reader returns the models' types; models never import formats), below experiments and
commands (which do the writing with :func:`distnav.output.atomic_write_text`).
"""
