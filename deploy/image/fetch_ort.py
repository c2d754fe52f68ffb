#!/usr/bin/env python3
"""Fetches one pinned ONNX Runtime wheel from PyPI, checks its SHA-256 and extracts only
its shared libraries (onnxruntime/capi/lib*.so*) into OUT_DIR, with libonnxruntime.so
linked to the versioned library: the image needs the libraries, not Python. A wheel is a
zip file.

usage: fetch_ort.py URL SHA256 OUT_DIR
"""

import hashlib
import os
import shutil
import ssl
import sys
import tempfile
import urllib.request
import zipfile


# Behind a TLS-intercepting proxy the build passes the proxy's CA as the build secret build_ca.
BUILD_CA = "/run/secrets/build_ca"


def main(url: str, sha256: str, out_dir: str) -> None:
    os.makedirs(out_dir, exist_ok=True)
    ca = BUILD_CA if os.path.isfile(BUILD_CA) and os.path.getsize(BUILD_CA) > 0 else None
    tls = ssl.create_default_context(cafile=ca)
    with tempfile.TemporaryFile() as wheel:
        digest = hashlib.sha256()
        with urllib.request.urlopen(url, timeout=300, context=tls) as r:
            while chunk := r.read(1 << 20):
                digest.update(chunk)
                wheel.write(chunk)
        if digest.hexdigest() != sha256:
            sys.exit(f"{url}: sha256 {digest.hexdigest()}, expected {sha256}")
        wheel.seek(0)
        with zipfile.ZipFile(wheel) as z:
            # Python's extension module (onnxruntime_pybind11_state*.so) is left out.
            libs = [n for n in z.namelist() if n.startswith("onnxruntime/capi/lib") and ".so" in n]
            if not any(os.path.basename(n).startswith("libonnxruntime.so") for n in libs):
                sys.exit(f"{url}: no libonnxruntime.so in the wheel")
            for name in libs:
                target = os.path.join(out_dir, os.path.basename(name))
                with z.open(name) as src, open(target, "wb") as dst:
                    shutil.copyfileobj(src, dst)
                os.chmod(target, 0o755)
                print(f"{target} ({os.path.getsize(target) / 1e6:.1f} MB)")
                # One path for every version: the image's B2TF_ORT_LIB names this link.
                if os.path.basename(name).startswith("libonnxruntime.so."):
                    link = os.path.join(out_dir, "libonnxruntime.so")
                    if os.path.lexists(link):
                        os.remove(link)
                    os.symlink(os.path.basename(name), link)


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    main(*sys.argv[1:])
