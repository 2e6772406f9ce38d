"""UWB file formats: range logs and position files (:mod:`.io`), the APRIL DW1000 logs (:mod:`.april`), the files of
a simulated hall (:mod:`.hall_files`). Modules are imported explicitly; nothing is imported here."""
