"""NumPy twins of every accelerated op: the same maths, plain and readable; the test reference."""

from .blur import (
    blur_adjoint,
    blur_adjoint_filter2d,
    blur_forward,
    blur_forward_filter2d,
)
from .warp import warp_cv2, warp_maps

__all__ = ["blur_adjoint", "blur_adjoint_filter2d", "blur_forward", "blur_forward_filter2d",
           "warp_cv2", "warp_maps"]
