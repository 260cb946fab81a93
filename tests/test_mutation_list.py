"""The mutation check's bugs still apply: each names code that exists exactly once (a refactor that
moves the code must move its mutation too, or the check silently tests nothing)."""

from pathlib import Path

import pytest

from tests.mutation import MUTATIONS

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("mutation", MUTATIONS, ids=[m.name for m in MUTATIONS])
def test_each_mutation_names_code_found_once(mutation):
    text = (ROOT / mutation.path).read_text()
    assert text.count(mutation.original) == 1, f"{mutation.path}: {mutation.original!r}"
    assert mutation.mutant != mutation.original and all((ROOT / t).exists() for t in mutation.tests)
