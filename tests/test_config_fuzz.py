"""The loader against seeded mutants of the shipped configs (tests/config_mutants.py): no traceback, only one-line
refusals naming the file, and no known nonsense accepted. ``benchmarks/bench_fuzz.py`` runs many more."""

from __future__ import annotations

import pytest
from config_mutants import check_mutant, mutants, nonsense_mutants

from bodebench.io.config import ConfigError, parse_config

SEEDS = (1, 2, 3)
MUTANTS_PER_SEED = 150


@pytest.mark.parametrize("seed", SEEDS)
def test_every_mutant_is_accepted_or_refused_in_one_line(seed: int) -> None:
    defects = [defect for mutant in mutants(seed, MUTANTS_PER_SEED) if (defect := check_mutant(mutant))]
    assert not defects, "\n".join(defects[:10])


def test_known_nonsense_is_refused_naming_the_key() -> None:
    checked = 0
    for key, mutant in nonsense_mutants():
        with pytest.raises(ConfigError) as refused:
            parse_config(mutant.data, mutant.source)
        message = str(refused.value)
        assert "\n" not in message and message.startswith(mutant.source), message
        name = key.split(".")[1]
        assert name.removesuffix("s") in message, (mutant.edits, message)  # the key, or its quantity in the relation
        checked += 1
    assert checked > 100  # every shipped config contributes its tables' edits
