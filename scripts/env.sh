# Sourced by the scripts: quiet Mesa's "XDG_RUNTIME_DIR is invalid" warning on headless machines.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
