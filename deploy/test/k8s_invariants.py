#!/usr/bin/env python3
"""What the schemas cannot check in rendered manifests (kubectl kustomize output):
the replicas never write the shared store, refuse writes server-side, and get enough time
to drain on SIGTERM; the onboarding Job is the store's writer.

usage: k8s_invariants.py RENDERED.yaml
"""
import sys

import yaml


def main(path: str) -> None:
    with open(path) as f:
        docs = {(d["kind"], d["metadata"]["name"]): d for d in yaml.safe_load_all(f) if d}
    config = docs[("ConfigMap", "b2tf-config")]["data"]
    pod = docs[("Deployment", "b2tfpose")]["spec"]["template"]["spec"]
    job = docs[("Job", "b2tf-onboard")]["spec"]["template"]["spec"]
    problems = []
    if config.get("B2TF_READ_ONLY") != "1":
        problems.append('ConfigMap b2tf-config: B2TF_READ_ONLY is not "1"')
    store = [v for v in pod["volumes"] if v.get("persistentVolumeClaim", {}).get("claimName") == "b2tf-store"]
    if not store or not store[0]["persistentVolumeClaim"].get("readOnly"):
        problems.append("Deployment: the b2tf-store claim is not mounted readOnly")
    for c in pod.get("initContainers", []) + pod["containers"]:
        for m in c.get("volumeMounts", []):
            if store and m["name"] == store[0]["name"] and not m.get("readOnly"):
                problems.append(f"Deployment container {c['name']}: store mount {m['mountPath']} is writable")
    for c in pod["containers"]:
        # The drain: preStop, then running estimates up to the request timeout.
        pre_stop = int(c["lifecycle"]["preStop"]["exec"]["command"][-1])
        needed = pre_stop + float(config["B2TF_REQUEST_TIMEOUT_S"])
        if pod["terminationGracePeriodSeconds"] <= needed:
            problems.append(f"terminationGracePeriodSeconds {pod['terminationGracePeriodSeconds']} ≤ preStop {pre_stop} s + request timeout {config['B2TF_REQUEST_TIMEOUT_S']} s")
        probes = {p: c[p]["httpGet"]["path"] for p in ("readinessProbe", "livenessProbe")}
        if probes != {"readinessProbe": "/readyz", "livenessProbe": "/healthz"}:
            problems.append(f"probes: {probes}")
    job_store = [v for v in job["volumes"] if v.get("persistentVolumeClaim", {}).get("claimName") == "b2tf-store"]
    if not job_store or job_store[0]["persistentVolumeClaim"].get("readOnly"):
        problems.append("Job b2tf-onboard does not mount b2tf-store writable")
    if problems:
        sys.exit(f"{path}:\n  " + "\n  ".join(problems))
    print(f"{path}: replicas read-only (volume and B2TF_READ_ONLY), drain fits the grace period, Job writes the store")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
