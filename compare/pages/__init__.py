"""Self-contained HTML pages: the run's 3D viewer (`viewer`) and a policy's training page (`training_view`),
with their assets and the JSON embedding (`embed`)."""
