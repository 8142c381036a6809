"""The references the paper's text ends with: those of the methods it names, in the order
it names them, and none for a method it does not apply."""

from __future__ import annotations

from pathlib import Path

from analysis import methods_text, presentation_text
from analysis.references import REFERENCES, cited


def test_references_follow_the_text_and_only_what_it_names():
    text = ("Scores from SUREAL (Li et al. 2020). Each metric: PLCC (ITU-T P.1401) after a "
            "5-parameter logistic mapping.")
    refs = cited(text)
    assert [r.split(" (")[0].split(":")[0] for r in refs] == [
        "Li, Z., Bampis, C. G., Krasula, L., Janowski, L., Katsavounidis, I.",
        "ITU-T Recommendation P.1401", "Sheikh, H. R., Sabir, M. F., Bovik, A. C."]
    assert cited("Plain means over all raters.") == []
    assert cited("CGVQM-2: PLCC 0.9; a one-tailed paired bootstrap")[0].startswith("Jindal")


def test_every_reference_is_reachable_from_the_text_that_names_methods():
    """A phrase no sentence can contain would leave its reference out for good."""
    source = "".join(Path(m.__file__).read_text() for m in (methods_text, presentation_text))
    for phrases, reference in REFERENCES:
        assert any(p in source for p in phrases), reference
