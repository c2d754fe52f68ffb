#!/usr/bin/env bash
# Offline schema checks of the deployment files (the validators carry their schemas:
# check-jsonschema vendors the compose specification's, kubernetes-validate Kubernetes').
#   validate.sh TOOLS_DIR      (TOOLS_DIR: where install-tools.sh put them)
set -euo pipefail
tools="$1"
deploy="$(cd "$(dirname "$0")/.." && pwd)"
py() { PYTHONPATH="$tools" python3 "$@"; }
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

# A validator that passes everything proves nothing: each must also reject a broken copy.
expect_rejected() {
  if "$@" >"$work/rejected.log" 2>&1; then echo "validator accepted a broken file: $*" >&2; exit 1; fi
}

# docker-compose.yml against the compose specification's JSON schema.
py -m check_jsonschema --builtin-schema vendor.compose-spec "$deploy/docker-compose.yml"
sed 's/^    restart: unless-stopped$/    restart: unless-stopped\n    no_such_key: 1/' "$deploy/docker-compose.yml" >"$work/bad-compose.yml"
expect_rejected py -m check_jsonschema --builtin-schema vendor.compose-spec "$work/bad-compose.yml"
# Monitoring configuration: well-formed, and the dashboard is a Grafana dashboard.
py -c 'import sys, yaml; [yaml.safe_load(open(p)) for p in sys.argv[1:]]' "$deploy"/monitoring/prometheus.yml "$deploy"/monitoring/grafana/provisioning/*/*.yml
py -c 'import json, sys; d = json.load(open(sys.argv[1])); assert d["uid"] and d["panels"], "not a dashboard"' "$deploy/monitoring/grafana/dashboards/b2tfpose.json"
echo "compose and monitoring files: valid"

# Kubernetes: each kustomization rendered, against the schemas of an older and the newest
# Kubernetes the validator knows, rejecting unknown fields (--strict).
for k in base overlays/gpu overlays/s3; do
  out="$work/$(basename "$k").yaml"
  kubectl kustomize "$deploy/k8s/$k" >"$out"
  for version in 1.30.0 1.37.0; do
    py -m kubernetes_validate --strict --quiet -k "$version" "$out"
  done
  py "$deploy/test/k8s_invariants.py" "$out"
  echo "k8s/$k: $(grep -c '^kind:' "$out") resources valid for Kubernetes 1.30 and 1.37"
done
# The invariants are checked too: an S3 overlay whose replicas get no credentials fails.
py - "$work/s3.yaml" "$work/bad-s3.yaml" <<'PY'
import sys, yaml
docs = [d for d in yaml.safe_load_all(open(sys.argv[1])) if d]
for d in docs:
    if d["kind"] == "Deployment":
        c = d["spec"]["template"]["spec"]["containers"][0]
        c["envFrom"] = [e for e in c["envFrom"] if "secretRef" not in e]
yaml.safe_dump_all(docs, open(sys.argv[2], "w"))
PY
expect_rejected py "$deploy/test/k8s_invariants.py" "$work/bad-s3.yaml"
grep -q "gets no credentials Secret" "$work/rejected.log" || { cat "$work/rejected.log" >&2; exit 1; }
sed 's/^  replicas: 2$/  replicas: 2\n  no_such_field: 1/' "$deploy/k8s/base/deployment.yaml" >"$work/bad-deployment.yaml"
expect_rejected py -m kubernetes_validate --strict --quiet "$work/bad-deployment.yaml"
echo "validators reject broken files: yes"
