"""What is flown: the strict scenario-file loader (`scenario`), the named task sets (`sets`), the generated
benchmark and sweep sets (`benchmark`, `sweep`) and their fingerprints (`fingerprint`). The shipped
scenario files live in `default/` and `full/` beside these modules."""
