#!/usr/bin/env bash
# Install the system pieces rtdefocus needs when they are missing:
#   an OpenCL ICD (PoCL on the CPU), Mesa EGL for offscreen GL, Xvfb for the window tests.
# Uses apt-get when root; otherwise prints the exact command to run and continues
# (the tests then skip what cannot run, with the reason).
set -u
need=()
if ! ls /etc/OpenCL/vendors/*.icd >/dev/null 2>&1; then need+=(pocl-opencl-icd ocl-icd-libopencl1); fi
if ! ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1'; then need+=(libegl1); fi
if ! ldconfig -p 2>/dev/null | grep -q 'libEGL_mesa.so.0'; then need+=(libegl-mesa0); fi
if ! ls /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1; then need+=(libgl1-mesa-dri); fi
if ! ldconfig -p 2>/dev/null | grep -q 'libglfw.so.3'; then :; fi  # glfw wheel ships its own
if ! command -v Xvfb >/dev/null 2>&1; then need+=(xvfb); fi
if [ ${#need[@]} -eq 0 ]; then exit 0; fi
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing system packages: ${need[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >/dev/null && apt-get install -y -qq "${need[@]}" >/dev/null \
        || { echo "apt-get install ${need[*]} failed" >&2; exit 1; }
else
    echo "missing system packages: ${need[*]}" >&2
    echo "run: sudo apt-get install -y ${need[*]}" >&2
fi
