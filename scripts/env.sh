# Sourced by the scripts: quiet Mesa's "XDG_RUNTIME_DIR is invalid" warning on headless machines.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
# ONNX Runtime's library and the tools' Python packages, as scripts/setup.sh installed them
# (a B2TF_ORT_LIB set by the caller wins).
_b2tf_deps="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)/.deps/python"
if [ -z "${B2TF_ORT_LIB:-}" ]; then
  for _lib in "$_b2tf_deps"/onnxruntime/capi/libonnxruntime.so.*; do
    [ -f "$_lib" ] && export B2TF_ORT_LIB="$_lib"
  done
fi
[ -d "$_b2tf_deps" ] && export PYTHONPATH="$_b2tf_deps${PYTHONPATH:+:$PYTHONPATH}"
unset _b2tf_deps _lib
