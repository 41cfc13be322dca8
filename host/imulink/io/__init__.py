"""Files: recordings, settings and calibration files, sensor and navigation CSVs, BROAD
trials, firmware images; each read with one-line errors and written atomically."""
