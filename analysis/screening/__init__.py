"""Screening out raters who disagree with the panel (``--outliers``): one module per rule.

- :mod:`.p913` (default): ITU-T P.913's correlation screening against the leave-one-out
  panel, iterated, confirmed by the MLE inconsistency estimate;
- :mod:`.grubbs`: the CGVQM+D paper's rule, kept to reproduce it;
- :mod:`.bt500`: ITU-R BT.500 kurtosis-based screening (as implemented in SUREAL);
- :mod:`.keep_all`: ``none``.

:mod:`.registry` finds the rules (every module defining ``RULE``) and runs one by name;
:mod:`.result` holds what a rule returns.
"""

from .registry import DEFAULT_METHOD, check_alpha, method_names, methods_help, rules, screen_raters
from .result import OutlierResult, RemovedRater

__all__ = ["DEFAULT_METHOD", "OutlierResult", "RemovedRater", "check_alpha", "method_names",
           "methods_help", "rules", "screen_raters"]
