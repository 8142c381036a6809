"""The screening rules are found by name, and the CLI lists them from that one registry."""

from __future__ import annotations

import pkgutil

import pytest

import analysis.screening as screening
from analysis.cli import build_parser
from analysis.errors import AnalysisError
from analysis.inputs import ratings_from_frame
from analysis.screening import DEFAULT_METHOD, method_names, rules, screen_raters
from analysis.screening.result import OutlierResult
from analysis.screening.rule import ScreeningRule
from analysis.synthetic import synthetic_study

NOT_RULES = {"registry", "result", "rule"}


def _report_help(capsys) -> str:
    with pytest.raises(SystemExit):
        build_parser().parse_args(["report", "--help"])
    return " ".join(capsys.readouterr().out.split())


def test_every_rule_module_is_registered_default_first() -> None:
    modules = {m.name for m in pkgutil.iter_modules(screening.__path__)} - NOT_RULES
    assert len(rules()) == len(modules)
    assert method_names() == ("p913", "grubbs", "bt500", "none")
    assert method_names()[0] == DEFAULT_METHOD


def test_cli_choices_and_help_come_from_the_registry(monkeypatch, capsys) -> None:
    extra = ScreeningRule(name="zz-test", order=99, summary="a rule added for this test",
                          screen=lambda rs: OutlierResult("zz-test", [], []))
    monkeypatch.setitem(rules(), extra.name, extra)
    text = _report_help(capsys)
    for rule in rules().values():
        assert rule.name in text and " ".join(rule.summary.split()) in text
    assert "{p913,grubbs,bt500,none,zz-test}" in text
    assert f"{DEFAULT_METHOD} (default: " in text


def test_an_unknown_rule_names_the_known_ones() -> None:
    st = synthetic_study(n_scenes=3, methods=("blur",), levels=2, n_raters=4, repetitions=1,
                         seed=0)
    rs = ratings_from_frame(st.ratings, st.manifest, source="test")
    with pytest.raises(AnalysisError, match="p913, grubbs, bt500, none"):
        screen_raters(rs, "nope")
    assert screen_raters(rs, "none").kept == list(range(rs.n_raters))
