"""What a technician edits: trial configs, calibration files and the rules every file the bench
reads obeys (strict models, safe YAML, one-line refusals), and the reference generated from them."""
