"""The campaign specs shipped in ``docs/campaigns/`` are valid and cover what they claim.

The acceptance matrix of a TE transition controller (``te_matrix.json``) and its
disturbance part (``te_disturbances.json``) are contracts: a typo in a case or a case
left out would silently shrink what a campaign judges.
"""

from __future__ import annotations

import json
from itertools import permutations
from pathlib import Path

import pytest

from services.campaign.spec import parse_spec

SPECS = Path(__file__).resolve().parents[1] / "docs" / "campaigns"


@pytest.mark.parametrize("path", sorted(SPECS.glob("*.json")), ids=lambda p: p.stem)
def test_every_shipped_spec_parses(path):
    spec = parse_spec(json.loads(path.read_text()), default_name=path.stem)
    assert spec.cases


def _spec(name):
    return parse_spec(json.loads((SPECS / name).read_text()))


def _cases(name):
    return _spec(name).cases


def test_the_matrix_holds_every_transition_disturbance_and_idv8_leg():
    cases = _cases("te_matrix.json")
    # 48 h, noise on, three seeds, for every case
    assert {(c.hours, c.noise, tuple(c.seeds)) for c in cases} == {(48.0, True, (1, 2, 3))}
    pairs = {(c.start, c.legs[0].grade) for c in cases if c.legs and not c.idvs}
    assert pairs == {(f"mode{a}", f"mode{b}") for a, b in permutations(range(4), 2)}
    alone = {(c.start, c.idvs[0].idv) for c in cases if not c.legs and len(c.idvs) == 1}
    assert alone == {(f"mode{m}", k) for m in (0, 2, 3) for k in range(1, 21)}
    assert all(c.idvs[0].on_h == 2.0 and c.idvs[0].off_h is None
               for c in cases if not c.legs)
    legs8 = {(c.start, c.legs[0].grade) for c in cases if c.legs and c.idvs}
    assert legs8 == {("mode0", "mode2"), ("mode2", "mode0")}


def test_the_disturbance_spec_is_the_matrix_disturbance_part():
    matrix = {c.name: c for c in _cases("te_matrix.json") if not c.legs}
    dist = {c.name: c for c in _cases("te_disturbances.json")}
    assert dist == matrix


def test_the_more_seeds_spec_is_the_matrix_on_seeds_it_does_not_run():
    """``te_matrix_seeds_4_9.json`` runs the matrix on six other plant seeds: the same
    cases, hours, noise and strategies, disjoint seeds."""
    matrix_spec, more_spec = _spec("te_matrix.json"), _spec("te_matrix_seeds_4_9.json")
    matrix = {c.name: c for c in matrix_spec.cases}
    more = {c.name: c for c in more_spec.cases}
    assert more.keys() == matrix.keys()
    for name, c in more.items():
        m = matrix[name]
        assert (c.start, c.legs, c.idvs, c.hours, c.noise) == (m.start, m.legs, m.idvs,
                                                                m.hours, m.noise)
        assert tuple(c.seeds) == (4, 5, 6, 7, 8, 9)
        assert not set(c.seeds) & set(m.seeds)
    assert more_spec.strategies == matrix_spec.strategies
