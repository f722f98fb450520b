"""How long the intruder stays after its robot needs the cell (``--intruder-stay``).

The paper's intruder leaves at a fixed ``T_d`` (10 s): 5 s after the robot it goes for was
estimated to start moving into its cell (``T_a`` + 2 s). A :class:`StaySpec` instead draws that
stay per run (per experiment: every variant of one experiment draws the same stay, from the
run's seed), from one of

* ``fixed:S`` -- always ``S`` seconds;
* ``uniform:A-B`` -- uniform on ``[A, B]`` seconds;
* ``lognormal:MEDIAN,SIGMA`` -- ``MEDIAN * exp(SIGMA * N(0, 1))`` seconds;
* ``exponential:MEAN`` -- exponential with mean ``MEAN`` seconds;
* ``FILE`` -- one of the stays (seconds, one a line, ``#`` comments) listed in a text file,
  uniformly.

A drawn stay is at least :data:`MIN_STAY_S` (a tenth of an action).
"""

from __future__ import annotations

import math
import random
import re
from dataclasses import dataclass
from pathlib import Path

from gateway.planning.seeds import run_seed

MIN_STAY_S = 0.1
"""The shortest stay drawn (s)."""
KINDS = ("fixed", "uniform", "lognormal", "exponential")
MAX_FILE_BYTES = 1_000_000
"""A stays file larger than this is refused."""


class StayError(ValueError):
    """A stay specification that cannot be used (the message is one line)."""


@dataclass(frozen=True)
class StaySpec:
    """A distribution of stays in seconds: ``kind`` with its ``params`` (``empirical``: the
    listed stays)."""

    kind: str
    params: tuple[float, ...]

    @property
    def text(self) -> str:
        """The canonical spelling (what a campaign's settings record)."""
        p = [f"{v:g}" for v in self.params]
        if self.kind == "uniform":
            return f"uniform:{p[0]}-{p[1]}"
        return f"{self.kind}:{','.join(p)}"

    def draw_s(self, rng: random.Random) -> float:
        """One stay in seconds."""
        kind, p = self.kind, self.params
        if kind == "fixed":
            value = p[0]
        elif kind == "uniform":
            value = rng.uniform(p[0], p[1])
        elif kind == "lognormal":
            value = p[0] * math.exp(p[1] * rng.gauss(0.0, 1.0))
        elif kind == "exponential":
            value = rng.expovariate(1.0 / p[0])
        else:
            value = p[rng.randrange(len(p))]
        return max(MIN_STAY_S, value)

    def draw_ms(self, seed: int) -> float:
        """The stay of the run of ``seed`` in ms (rounded to whole ms)."""
        return float(round(1000.0 * self.draw_s(random.Random(run_seed(seed, "stay")))))


def _numbers(kind: str, body: str, sep: str, count: int) -> tuple[float, ...]:
    parts = re.split(rf"(?<![eE]){re.escape(sep)}", body)
    try:
        values = tuple(float(x) for x in parts)
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise StayError(f"{kind}:{body}: expected {count} number(s) separated by {sep!r}")
    return values


def parse_stay(text: str) -> StaySpec:
    """The stay distribution of ``text`` (see the module's docstring); StayError if bad."""
    kind, colon, body = text.partition(":")
    if colon and kind in KINDS:
        if kind == "fixed":
            (s,) = _numbers(kind, body, ",", 1)
            if not s > 0:
                raise StayError(f"{text}: the stay must be > 0 s")
            return StaySpec(kind, (s,))
        if kind == "uniform":
            a, b = _numbers(kind, body, "-", 2)
            if not 0 <= a <= b or b == 0:
                raise StayError(f"{text}: need 0 <= A <= B and B > 0 (seconds)")
            return StaySpec(kind, (a, b))
        if kind == "lognormal":
            median, sigma = _numbers(kind, body, ",", 2)
            if not (median > 0 and sigma >= 0):
                raise StayError(f"{text}: need MEDIAN > 0 and SIGMA >= 0")
            return StaySpec(kind, (median, sigma))
        (mean,) = _numbers(kind, body, ",", 1)
        if not mean > 0:
            raise StayError(f"{text}: the mean must be > 0 s")
        return StaySpec(kind, (mean,))
    if kind == "empirical" and colon:
        values = tuple(float(v) for v in body.split(",") if v)
        return StaySpec("empirical", values)
    return _from_file(text)


def _from_file(text: str) -> StaySpec:
    path = Path(text)
    if not path.is_file():
        raise StayError(f"{text!r} is not fixed:S, uniform:A-B, lognormal:MEDIAN,SIGMA, "
                        "exponential:MEAN or a file of stays")
    try:
        if path.stat().st_size > MAX_FILE_BYTES:
            raise StayError(f"{text}: larger than {MAX_FILE_BYTES} bytes")
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise StayError(f"cannot read the stays file {text}: {exc}") from None
    values = []
    for number, line in enumerate(lines, start=1):
        item = line.split("#", 1)[0].strip()
        if not item:
            continue
        try:
            value = float(item)
        except ValueError:
            raise StayError(f"{text}:{number}: {item!r} is not a number of seconds") from None
        if not (value > 0 and math.isfinite(value)):
            raise StayError(f"{text}:{number}: a stay must be a positive number of seconds")
        values.append(value)
    if not values:
        raise StayError(f"{text}: no stay listed")
    return StaySpec("empirical", tuple(values))


STAY_HELP = ("the intruder's stay after its robot needs the cell, drawn per run from its seed: "
             "fixed:S, uniform:A-B, lognormal:MEDIAN,SIGMA, exponential:MEAN (seconds) or a "
             "FILE of stays in seconds, one a line (default: the paper's, it leaves at "
             "T_d = 10 s)")
"""The ``--intruder-stay`` option's help."""


def stay_option(text: str | None) -> StaySpec | None:
    """``--intruder-stay`` of a command (None: not given); a one-line UsageError if bad."""
    from gateway.runtime.exits import UsageError

    if text is None:
        return None
    try:
        return parse_stay(text)
    except StayError as exc:
        raise UsageError(f"--intruder-stay: {exc}") from None
