"""Files: the strict YAML reader every user file goes through and the checks of what it holds
(`strict`: unknown and missing keys, numbers, ranges, pairs and triples), atomic output, and which
code wrote an output (version and commit)."""
