"""OpenCL (``*.cl``) and GLSL (``*.glsl``) sources, shipped as package data of
``rtdefocus.kernels``; load them with :func:`rtdefocus.resources.kernel_source`."""
