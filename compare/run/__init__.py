"""Running a comparison: the campaign (`campaign`), its cells (`cells`), the backends that fly them
(`backends`) and the check of each cell's air against its pilot's training (`trained_air`)."""
