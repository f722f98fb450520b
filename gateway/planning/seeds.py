"""Seeds derived from a run's or a campaign's seed, in one place: every consumer of
randomness gets its own stream from these two derivations.

* :func:`derive_seed` (``numpy.random.SeedSequence`` over ints and names): the campaign's
  instance generator seeds and experiment seeds, the oracle's sample.
* :func:`run_seed` (``random.Random`` seeded with ``"purpose/seed"``): the streams of one
  simulated run (the intruder's choices, the random replan policy's time), in the
  discrete-event simulator, the simulated fleet and the demo alike.

Two algorithms because both are load-bearing: the campaigns, the tests' hand-derived seed
outcomes and the README's figures were drawn with them, and folding one into the other
re-draws either the campaign's instances or every run's intruder (the same statistics,
different numbers, and tests whose expected values no longer hold).
"""

from __future__ import annotations

import random
import zlib


def derive_seed(*parts: int | str, bits: int = 63) -> int:
    """A stable seed of ``bits`` bits from ints and strings (independent of PYTHONHASHSEED)."""
    import numpy as np  # here: the CLI's parser imports run_seed's module (no numpy at --help)

    entropy = [zlib.crc32(p.encode()) if isinstance(p, str) else int(p) for p in parts]
    state = np.random.SeedSequence(entropy).generate_state(2, dtype=np.uint64)
    return int(state[0]) >> (64 - bits)


def run_seed(seed: int, purpose: str) -> int:
    """An independent 64-bit seed for one consumer of randomness (``purpose``) in the run of
    seed ``seed``."""
    return random.Random(f"{purpose}/{seed}").getrandbits(64)
