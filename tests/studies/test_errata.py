"""Errata as data: the committed docs/errata.md is the generated one, and a row shared by several cases
is listed, once declared, for each of them."""

import pytest

import studies
from studies import errata


def registered():
    return [studies.get(n) for n in studies.names()]


def test_committed_document_equals_the_generated_one():
    assert errata.DOC.read_text(encoding="utf-8") == errata.document(registered()), (
        "docs/errata.md is stale: run python -m studies.errata --write-docs"
    )


def test_a_shared_row_is_declared_once_and_listed_for_every_case_it_concerns():
    item = "I.11(c), II.11, III.11, IV.12, V.12, VI.11"
    declared = [
        case.plant for case in registered() for e in case.errata if isinstance(e, errata.Erratum) and e.item == item
    ]
    assert declared == ["arm"]
    for case in registered():
        rows = errata.errata_of(case, registered())
        assert [r["item"] for r in rows].count(item) == 1
        assert {r["section"] for r in rows} <= {title for title, _, _ in errata.SECTIONS.values()}


def test_a_row_must_fill_its_table():
    with pytest.raises(ValueError, match="has 2 columns after the item"):
        errata.Erratum("text", "X.1", ("only one cell",))
    with pytest.raises(ValueError, match="unknown errata section 'typo'"):
        errata.Erratum("typo", "X.1", ("a", "b"))
