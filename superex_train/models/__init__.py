"""Networks: the Pix2Pix back-projection filter and the LaMa (FFC) map predictor."""

from superex_train.models.common import calibrate_batchnorm, count_parameters
from superex_train.models.lama import (FFC, DftBasis, FFCResBlock, FourierUnit, LamaConfig, LamaGenerator,
                                       SpectralBackend, SpectralTransform, dft_basis, irfft2_ortho, rfft2_ortho)
from superex_train.models.pix2pix import PatchDiscriminator, Pix2PixConfig, UNetGenerator

__all__ = ["FFC", "DftBasis", "FFCResBlock", "FourierUnit", "LamaConfig", "LamaGenerator", "SpectralBackend",
           "SpectralTransform", "dft_basis", "irfft2_ortho", "rfft2_ortho", "PatchDiscriminator", "Pix2PixConfig",
           "UNetGenerator", "calibrate_batchnorm", "count_parameters"]
