"""Classical full-reference image metrics as plain torch functions, one per metric.

Every function takes a test and a reference batch ``(B, 3, H, W)`` of RGB in [0, 1] (float32
or float64, any device) and returns one number per image ``(B,)``. Definitions, defaults,
colour handling and internal down-sampling follow PIQ 0.8 (Kastryulin et al.), which the
CGVQM paper used for its image-metric baselines; the test suite checks each function against
PIQ itself. Images are independent: a batch gives the numbers each image gives alone (PIQ's
SR-SIM normalises the saliency over the whole batch; here it is per image, which is what PIQ
gives for one frame at a time, the paper's per-frame protocol).
"""

from .dss import dss
from .fsim import fsim
from .gmsd import gmsd, ms_gmsd
from .haarpsi import haarpsi
from .iw_ssim import iw_ssim
from .mdsi import mdsi
from .psnr import psnr
from .srsim import srsim
from .ssim import MS_SSIM_WEIGHTS, ms_ssim, ms_ssim_min_size, ssim
from .vif import vif_p
from .vsi import vsi

__all__ = ["MS_SSIM_WEIGHTS", "dss", "fsim", "gmsd", "haarpsi", "iw_ssim", "mdsi", "ms_gmsd",
           "ms_ssim", "ms_ssim_min_size", "psnr", "srsim", "ssim", "vif_p", "vsi"]
