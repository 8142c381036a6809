"""CGVQM, the computer-graphics video quality metric (Jindal et al., CGF 2025).

Numerically the authors' metric (same backbone, weights and patch semantics), streamed clip
by clip so memory does not grow with video length, with a fast path on CPU, reference reuse
across test videos, error-map videos and safe weight loading.

    from cgvqm_core import CGVQM
    result = CGVQM("cgvqm-2").score("ref.mp4", "test.mp4", pool="max")
    print(result.q, result.label)
"""

import os
import sys

from .version import __version__

# Large CPU tensors on transparent huge pages: the metric allocates many activations of tens
# of MB, and first-touch page faults otherwise cost as much as the arithmetic on them. Only
# effective when torch has not been imported yet; set THP_MEM_ALLOC_ENABLE=0 to opt out.
if "torch" not in sys.modules:
    os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")

from .errors import CGVQMError
from .metric import CGVQM, LABELS, CGVQMResult, pool_errors, quality_label
from .stream import StreamOutput, patch_channel_msd
from .weights import (
    VARIANTS,
    FeatureWeights,
    load_weights,
    save_weights,
)

__all__ = [
    "CGVQM",
    "LABELS",
    "VARIANTS",
    "CGVQMError",
    "CGVQMResult",
    "FeatureWeights",
    "StreamOutput",
    "__version__",
    "load_weights",
    "patch_channel_msd",
    "pool_errors",
    "quality_label",
    "save_weights",
]
