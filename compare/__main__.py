"""`python -m compare` is the same as the `uam-compare` console script."""
import sys

from compare.cli import main

sys.exit(main())
