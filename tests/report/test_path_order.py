"""result.json and the report say which way round and from where the run follows the CAD path."""

import html
from types import SimpleNamespace

from refine.export.result_json import _demo_quality
from refine.paths import PathOrder
from refine.report.html import _order_html


class _Quality:
    def as_json(self):
        return {"n_samples": 10}


def _result(order):
    return SimpleNamespace(fused=SimpleNamespace(order=order), demo_quality=_Quality())


def test_the_choice_is_added_to_demo_quality():
    order = PathOrder("reversed", 0.9095, "alignment", "alignment", 0.2956, 0.0371)
    doc = _demo_quality(_result(order))
    assert doc["n_samples"] == 10
    assert doc["direction"] == "reversed" and doc["start_offset_m"] == 0.9095
    assert doc["direction_residual_as_cad_m"] == 0.2956 and doc["direction_residual_reversed_m"] == 0.0371
    assert doc["direction_source"] == "alignment" and doc["start_source"] == "alignment"


def test_the_report_states_direction_start_and_both_distances():
    page = html.unescape(
        _order_html(_result(PathOrder("reversed", 0.9094, "alignment", "alignment", 0.2956, 0.0371)))
    )
    assert "against the CAD file's order (reversed)" in page
    assert "295.6 mm as drawn, 37.1 mm reversed" in page and "starts 0.909 m along" in page


def test_an_override_is_named_as_the_problem_s():
    page = _order_html(_result(PathOrder("as_cad", 0.0, "problem", "open path")))
    assert "set by the problem" in page and "an end of the open path" in page
    assert _order_html(_result(None)) == ""
