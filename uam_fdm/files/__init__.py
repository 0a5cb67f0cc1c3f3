"""Files: the strict YAML reader every user file goes through, atomic output, and which code wrote
an output (version and commit)."""
