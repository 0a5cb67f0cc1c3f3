"""The PDF report and the matplotlib figures it is made of. Reads saved results only (through
`compare.results`); never simulates."""
