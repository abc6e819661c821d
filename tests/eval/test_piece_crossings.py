"""The evaluation's piece crossings: summed over a set's instances where any record counts them
(garments of several pieces), and a column of the tables only then."""

from physdrape.eval.report import _table
from physdrape.eval.summary import summary


def _record(crossings=None, energy=1.0):
    record = {"strain": 0.1, "bend": 0.01, "b2g_percent": 0.0, "close_percent": 0.0, "residual_force": 0.0,
              "residual_relative": 0.0, "energy_total": energy, "wall_s": 0.1}
    if crossings is not None:
        record["piece_crossings"] = crossings
    return record


def test_summary_sums_the_crossings_where_any_record_counts_them():
    assert summary([_record(3), _record(0), _record(5)])["piece_crossings"] == 8
    assert summary([_record(3), _record()])["piece_crossings"] == 3  # a garment of one piece: none
    assert "piece_crossings" not in summary([_record(), _record()])


def test_the_table_has_a_crossings_column_only_for_garments_worn_in_pieces():
    pieces = _table([("row", summary([_record(2), _record(1)]))], timing=False, oracle=False)
    assert "piece crossings (sum)" in pieces[0]
    assert pieces[2].split(" | ")[-1].rstrip(" |") == "3"
    single = _table([("row", summary([_record(), _record()]))], timing=False, oracle=False)
    assert "piece crossings" not in single[0]
