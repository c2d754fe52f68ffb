#!/usr/bin/env bash
# What deploy/test.sh needs, installed only when missing: buildah and mmdebstrap (Debian),
# kubectl (its built-in kustomize renders deploy/k8s; from the Kubernetes/Google apt
# repository where Debian's has none) and, pinned into .deps/deploy-tools of the checkout,
# check-jsonschema (carries the compose specification's schema) and kubernetes-validate
# (carries the Kubernetes schemas), so validation works offline.
set -euo pipefail
repo="$(cd "$(dirname "$0")/../.." && pwd)"
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
need=()
command -v buildah >/dev/null || need+=(buildah)
command -v mmdebstrap >/dev/null || need+=(mmdebstrap)
command -v kubectl >/dev/null || need+=(kubectl)
if [ ${#need[@]} -gt 0 ]; then
  echo "installing: ${need[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
fi
tools="$repo/.deps/deploy-tools"
stamp="$tools/check-jsonschema-0.39.0+kubernetes-validate-1.37.0.installed"
if [ ! -f "$stamp" ]; then
  rm -rf "$tools"
  python3 -m pip install --quiet --disable-pip-version-check --target "$tools" \
    "check-jsonschema==0.39.0" "kubernetes-validate==1.37.0"
  touch "$stamp"
fi
