"""GNSS file formats: RINEX observation (:mod:`.rinex_obs`, :mod:`.rinex`) and navigation (:mod:`.rinex_nav`)
files, SP3 (:mod:`.rinex`), Bias-SINEX and IONEX DCB blocks (:mod:`.bias_sinex`), published products
(:mod:`.product_files`). Modules are imported explicitly; nothing is imported here."""
