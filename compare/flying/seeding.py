"""One seed drives everything: derived seeds for each comparison cell.

A cell (scenario, episode, seed) gets one derived integer from `numpy.random.SeedSequence`, which
seeds the turbulence realisation (the same for every pilot: all fly the same air) and
the pilot (OMPL's RNG for the classical pilot; the learned pilot acts deterministically) and the sensors
(every pilot meets the same sensor noise on a cell: paired comparisons share it as they share the air). The
derivation depends only on the cell, never on the order or the process it runs in, so a run gives
the same numbers with any number of parallel jobs.
"""
from __future__ import annotations

import zlib

import numpy as np


def cell_seed(scenario: str, episode: int, seed: int, stream: str) -> int:
    """A 31-bit seed for one cell and one use (`stream`: "wind", or "agent" for the pilot: the
    stream's first name, kept because it is hashed into the seed)."""
    words = [int(seed) & 0xFFFFFFFF, int(seed) >> 32, int(episode), zlib.crc32(scenario.encode()),
             zlib.crc32(stream.encode())]
    return int(np.random.SeedSequence(words).generate_state(1)[0] & 0x7FFFFFFF)
