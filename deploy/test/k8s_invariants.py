#!/usr/bin/env python3
"""What the schemas cannot check in rendered manifests (kubectl kustomize output):
the replicas never write the shared store, refuse writes server-side, and get enough time
to drain on SIGTERM; the onboarding Job is the store's writer. A volume store: the replicas
mount it read-only, the Job writable. An S3 store (B2TF_STORE=s3://...): no volume at all,
and the replicas and the Job both get the bucket's settings and credentials.

usage: k8s_invariants.py RENDERED.yaml
"""

import sys

import yaml


def env_sources(spec: dict) -> set:
    """The ConfigMaps and Secrets a pod's first container takes whole (envFrom)."""
    out = set()
    for e in spec["containers"][0].get("envFrom", []):
        for kind, key in (("ConfigMap", "configMapRef"), ("Secret", "secretRef")):
            if key in e:
                out.add((kind, e[key]["name"]))
    return out


def check_s3(docs: dict, pod: dict, job: dict) -> list:
    problems = []
    if any(kind == "PersistentVolumeClaim" and name == "b2tf-store" for kind, name in docs):
        problems.append("S3 store, yet the b2tf-store claim is still there")
    for who, spec in (("Deployment", pod), ("Job b2tf-onboard", job)):
        if any("persistentVolumeClaim" in v for v in spec.get("volumes", [])):
            problems.append(f"{who}: mounts a volume claim although the store is S3")
        sources = env_sources(spec)
        for kind, name in sources:
            if kind != "ConfigMap" or name != "b2tf-config":
                if (kind, name) not in docs:
                    problems.append(f"{who}: envFrom names {kind} {name}, which is not in the manifests")
        if not any(kind == "Secret" for kind, _ in sources):
            problems.append(f"{who}: gets no credentials Secret for the bucket")
        if not any(kind == "ConfigMap" and name != "b2tf-config" for kind, name in sources):
            problems.append(f"{who}: gets no AWS_* settings ConfigMap for the bucket")
    return problems


def main(path: str) -> None:
    with open(path) as f:
        docs = {(d["kind"], d["metadata"]["name"]): d for d in yaml.safe_load_all(f) if d}
    config = docs[("ConfigMap", "b2tf-config")]["data"]
    pod = docs[("Deployment", "b2tfpose")]["spec"]["template"]["spec"]
    job = docs[("Job", "b2tf-onboard")]["spec"]["template"]["spec"]
    problems = []
    if config.get("B2TF_READ_ONLY") != "1":
        problems.append('ConfigMap b2tf-config: B2TF_READ_ONLY is not "1"')
    on_s3 = config["B2TF_STORE"].startswith("s3://")
    store = [v for v in pod["volumes"] if v.get("persistentVolumeClaim", {}).get("claimName") == "b2tf-store"]
    if on_s3:
        problems += check_s3(docs, pod, job)
    elif not store or not store[0]["persistentVolumeClaim"].get("readOnly"):
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
    if not on_s3 and (not job_store or job_store[0]["persistentVolumeClaim"].get("readOnly")):
        problems.append("Job b2tf-onboard does not mount b2tf-store writable")
    if problems:
        sys.exit(f"{path}:\n  " + "\n  ".join(problems))
    where = "an S3 bucket, no volume" if on_s3 else "volume and B2TF_READ_ONLY"
    print(f"{path}: replicas read-only ({where}), drain fits the grace period, Job writes the store")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
