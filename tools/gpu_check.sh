#!/usr/bin/env bash
# tools/gpu_check.sh [--dry-run] [OUT_DIR]
#
# One short run on a machine with an NVIDIA GPU and no network:
#   1. Python: the tree's .venv if it imports rtdefocus and pyopencl, else a fresh venv
#      installed offline from wheels/ (carried with the tree; see below);
#   2. the NVIDIA OpenCL ICD file /etc/OpenCL/vendors/nvidia.icd (libnvidia-opencl.so.1) if the
#      driver library is there and no ICD names it (root only; otherwise it says what to run);
#   3. `rtdefocus info`, tools/bench.py (blur + iteration at 800x600), tools/bench_video.py
#      (compensate() cost per variant, and `eval --video --quick`), each under a timeout;
#   4. every figure as JSON in OUT_DIR (default: $OUT, else gpu_check_out/): gpu_check.json
#      (device, per-step status and seconds, the benchmark rows, the video summary) and the
#      logs and files of each step.
# --dry-run: the same end to end on whatever OpenCL device there is (PoCL here), without
# writing the ICD file; a check of the script itself on a machine without a GPU.
#
# Filling wheels/ (on a machine with network, for the GPU machine's Python and platform):
#   python3 -m pip download -d wheels --only-binary=:all: \
#       --python-version 3.11 --platform manylinux2014_x86_64 --platform manylinux_2_28_x86_64 \
#       pyopencl moderngl glcontext glfw numpy opencv-python-headless scipy scikit-image \
#       matplotlib tqdm setuptools wheel pytools platformdirs typing-extensions siphash24
#   (match --python-version to `python3 --version` there). wheels/ is not ignored by git on
#   purpose, so a device run carries it with the working tree; do not commit it.
set -uo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
DRY=0
DEST=""
for a in "$@"; do
    case "$a" in
        --dry-run) DRY=1 ;;
        -h|--help) sed -n '2,27p' "$0"; exit 0 ;;
        -*) echo "unknown option $a (see --help)" >&2; exit 2 ;;
        *) DEST=$a ;;
    esac
done
DEST=${DEST:-${OUT:-gpu_check_out}}
mkdir -p "$DEST"
DEST=$(cd "$DEST" && pwd)
STEPS="$DEST/steps.tsv"
: > "$STEPS"
say() { echo "[gpu_check] $*"; }

step() {   # step NAME TIMEOUT_S CMD... : run, log, record status and seconds
    local name=$1 limit=$2; shift 2
    local t0=$(date +%s.%N)
    say "$name: $*"
    timeout "$limit" "$@" > "$DEST/$name.log" 2>&1
    local rc=$?
    local dt=$(python3 -c "import time; print(round(time.time() - $t0, 1))" 2>/dev/null || echo 0)
    printf '%s\t%s\t%s\n' "$name" "$rc" "$dt" >> "$STEPS"
    tail -n 25 "$DEST/$name.log"
    [ "$rc" = 0 ] || say "$name failed (exit $rc; log $DEST/$name.log)"
    return 0
}

# ---- 1. Python
PY="$ROOT/.venv/bin/python"
if ! { [ -x "$PY" ] && "$PY" -c "import rtdefocus, pyopencl, moderngl" 2>/dev/null; }; then
    VENV=${VENV:-/tmp/rtdefocus-gpu-venv}
    if [ ! -d "$ROOT/wheels" ]; then
        say "no usable .venv and no wheels/ folder: fill wheels/ as the header says" >&2
        exit 1
    fi
    say "installing offline from wheels/ into $VENV"
    python3 -m venv "$VENV" || exit 1
    "$VENV/bin/python" -m pip install -q --no-index --find-links "$ROOT/wheels" \
        "$ROOT[demo]" > "$DEST/install.log" 2>&1 || { tail -20 "$DEST/install.log"; exit 1; }
    PY="$VENV/bin/python"
fi
RD=("$PY" -m rtdefocus)

# ---- 2. the NVIDIA OpenCL ICD
ICD_NOTE="not needed"
NVLIB=$(ldconfig -p 2>/dev/null | awk '/libnvidia-opencl\.so\.1/ {print $NF; exit}')
if [ -n "$NVLIB" ]; then
    if grep -qs libnvidia-opencl /etc/OpenCL/vendors/*.icd; then
        ICD_NOTE="present"
    elif [ "$DRY" = 1 ]; then
        ICD_NOTE="dry run: would write /etc/OpenCL/vendors/nvidia.icd"
    elif [ "$(id -u)" = 0 ]; then
        mkdir -p /etc/OpenCL/vendors && echo "libnvidia-opencl.so.1" > /etc/OpenCL/vendors/nvidia.icd
        ICD_NOTE="written"
    else
        ICD_NOTE="missing; run: echo libnvidia-opencl.so.1 | sudo tee /etc/OpenCL/vendors/nvidia.icd"
    fi
else
    ICD_NOTE="no libnvidia-opencl.so.1 (no NVIDIA driver)"
fi
say "NVIDIA OpenCL ICD: $ICD_NOTE"
command -v nvidia-smi >/dev/null && nvidia-smi > "$DEST/nvidia-smi.txt" 2>&1
if [ "$DRY" = 0 ] && [ -n "$NVLIB" ]; then export RTDEFOCUS_DEVICE=${RTDEFOCUS_DEVICE:-nvidia}; fi

# ---- 3. the runs (EGL offscreen for the GL warp; cv2 is the fallback there)
step info 120 "${RD[@]}" info
step bench 300 "$PY" tools/bench.py --sections blur,iteration --sizes 800x600 --radii 5 \
    --quick --out "$DEST/bench"
step bench_video 300 "$PY" tools/bench_video.py --sections cost --repeats 5 --out "$DEST/bench"
step eval_video 300 "${RD[@]}" -q eval --video --quick -o "$DEST/eval_video"

# ---- 4. one JSON with everything
"$PY" - "$DEST" "$ICD_NOTE" "$DRY" <<'EOF'
import glob, json, os, sys
dest, icd, dry = sys.argv[1], sys.argv[2], sys.argv[3] == "1"
out = {"dry_run": dry, "icd": icd, "steps": {}}
for line in open(os.path.join(dest, "steps.tsv")):
    name, rc, secs = line.rstrip("\n").split("\t")
    out["steps"][name] = {"exit": int(rc), "seconds": float(secs)}
info = os.path.join(dest, "info.log")
out["info"] = open(info).read() if os.path.exists(info) else None
for f in sorted(glob.glob(os.path.join(dest, "bench", "*.json"))):
    data = json.load(open(f))
    key = "bench_video" if os.path.basename(f).startswith("video-") else "bench"
    out.setdefault("machine", data.get("machine"))
    out[key] = data.get("cost") if key == "bench_video" else data.get("rows")
v = os.path.join(dest, "eval_video", "video.json")
if os.path.exists(v):
    data = json.load(open(v))
    out["eval_video"] = {"settings": data["settings"], "summary": data["summary"],
                         "machine": data.get("machine")}
json.dump(out, open(os.path.join(dest, "gpu_check.json"), "w"), indent=1)
failed = [n for n, s in out["steps"].items() if s["exit"] != 0]
print(f"[gpu_check] wrote {os.path.join(dest, 'gpu_check.json')}; device: "
      f"{(out.get('machine') or {}).get('device')}; failed steps: {failed or 'none'}")
sys.exit(1 if failed else 0)
EOF
