"""NumPy twins of every accelerated op: the same maths, plain and readable; the test reference."""

from .blur import (
    blur_adjoint,
    blur_adjoint_filter2d,
    blur_forward,
    blur_forward_filter2d,
)

__all__ = ["blur_adjoint", "blur_adjoint_filter2d", "blur_forward", "blur_forward_filter2d"]
