#!/usr/bin/env bash
# The console's browser test (browser_test.py): installs Debian's chromium and its driver
# when absent, and Selenium (pinned) into .deps/console-venv; runs against $B2TF_BIN
# (default: target/debug/b2tf, built by cargo when missing). Screenshots: out/console-test.
set -euo pipefail
REPO="$(cd "$(dirname "$0")/../.." && pwd)"
cd "$REPO"
# scripts/env.sh puts .deps/python on PYTHONPATH: pip would take its packages
# (typing_extensions) as installed and leave them out of the venv.
unset PYTHONPATH
SUDO=""; [ "$(id -u)" = 0 ] || SUDO=sudo
need=()
for pkg in chromium chromium-driver python3-venv; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
  echo "installing: ${need[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
fi
VENV="$REPO/.deps/console-venv"
SELENIUM=4.51.0
if ! "$VENV/bin/python" -c "import selenium, sys; sys.exit(selenium.__version__ != '$SELENIUM')" >/dev/null 2>&1; then
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install --quiet --disable-pip-version-check "selenium==$SELENIUM"
fi
export B2TF_BIN="${B2TF_BIN:-target/debug/b2tf}"
[ -x "$B2TF_BIN" ] || ( source scripts/env.sh && cargo build )
# Selenium must not fetch a driver or browser of its own: the system's are given.
export SE_OFFLINE=true CHROMIUM=/usr/bin/chromium CHROMEDRIVER=/usr/bin/chromedriver
exec "$VENV/bin/python" console/test/browser_test.py
