"""About a thousand fuzz cases per test run (``make fuzz`` runs 10^5; see
``tests/fuzzing.py``): never a traceback, never a disagreement with the oracle."""

from __future__ import annotations

import warnings

import fuzzing
import pytest

CASES = {"soup": 150, "hostile_soup": 500, "cell_file": 150, "cell_text": 150, "cli": 50,
         "out_folder": 30, "replay": 10, "write_failure": 4, "run_folder": 20, "recording": 8,
         "sweep_resume": 6}


SLOW = {"write_failure", "recording", "sweep_resume"}  # 15-20 s each: in make test-slow


@pytest.mark.parametrize("kind", [pytest.param(k, marks=pytest.mark.slow) if k in SLOW else k
                                  for k in fuzzing.KINDS])
def test_fuzz(kind: str):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # overflow from the hostile values
        tally = fuzzing.run_kind(kind, CASES[kind], seed=7)
    assert not tally.failures, f"{len(tally.failures)} failures, first: {tally.failures[:3]}"
    assert tally.cases == CASES[kind]
    if kind == "soup":
        kept = tally.queries - tally.ambiguous
        assert tally.ambiguous <= 0.02 * tally.queries and 0.05 * kept < tally.hidden < 0.95 * kept
    else:  # the hostile kinds reach the error paths
        assert 0 < tally.refused <= tally.cases
