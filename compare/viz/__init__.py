"""Showing results: figures, the PDF report, flights grouped for playback, the animation and the
HTML viewer. Reads saved results only (through `compare.results`); never simulates."""
