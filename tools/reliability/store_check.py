"""Whether a store holds only complete objects, as the crash and full-disk tests need to
know after every kill: through a running server (each listed object fetched and
estimated, which decodes all of it and must give the photo's known pose), on disk (no
hidden temporary folders left once a writer has reopened a dir:// store), and offline with
the CLI (`b2tf objects list` and `objects show --load`) plus SQLite's integrity check."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Dict, List

from .calls import http_call
from .fixtures import Fixtures, pose_is_right
from .server import run_cli


def listed(http: str) -> List[str]:
    r = http_call(http, "GET", "/v1/objects", timeout=60)
    if r.status != "200":
        raise RuntimeError(f"GET /v1/objects -> {r.status} {r.detail} {r.body!r}")
    return sorted(o["id"] for o in json.loads(r.body)["objects"])


def check_served(http: str, fx: Fixtures, templates: Dict[str, int]) -> List[str]:
    """Problems with the objects a server lists: each must be fetched with the template
    count it was onboarded with (`templates` by id prefix, e.g. {"crash-": 144}) and
    estimated to the right pose. Ids matching no prefix are problems too."""
    problems: List[str] = []
    for oid in listed(http):
        want = next((n for prefix, n in templates.items() if oid.startswith(prefix)), None)
        if want is None:
            problems.append(f"{oid}: an object nobody onboarded")
            continue
        g = http_call(http, "GET", f"/v1/objects/{oid}", timeout=60)
        if g.status != "200":
            problems.append(f"{oid}: GET -> {g.status} {g.detail} {g.body!r}"[:300])
            continue
        if json.loads(g.body).get("templates") != want:
            problems.append(f"{oid}: {json.loads(g.body).get('templates')} templates, expected {want}")
        e = http_call(http, "POST", "/v1/estimate", fx.estimate_json(oid), timeout=120)
        if e.status != "200":
            problems.append(f"{oid}: estimate -> {e.status} {e.detail} {e.body!r}"[:300])
            continue
        res = json.loads(e.body)["results"][0]
        if not res.get("pose") or not pose_is_right(res["pose"]["t"]):
            problems.append(f"{oid}: estimate gave a wrong pose: {json.dumps(res)[:200]}")
    return problems


def hidden_folders(store_dir: Path) -> List[str]:
    """A dir:// store's hidden temporary folders (`.ID.tmp-PID-N`, `.ID.old-…`): none may
    be left once a writer reopened the store after its predecessor died."""
    return sorted(p.name for p in store_dir.iterdir() if p.name.startswith(".")) if store_dir.is_dir() else []


def check_offline(store_url: str) -> List[str]:
    """With no server running: the CLI lists the store and loads every object fully; a
    SQLite file passes PRAGMA integrity_check."""
    problems: List[str] = []
    try:
        objects = json.loads(run_cli("objects", "list", "--store", store_url, "--json"))
        ids = [o["id"] for o in (objects["objects"] if isinstance(objects, dict) else objects)]
        for oid in ids:
            run_cli("objects", "show", oid, "--load", "--store", store_url)
    except RuntimeError as e:
        problems.append(f"offline CLI check of {store_url}: {e}"[:600])
    if store_url.startswith("sqlite://"):
        path = store_url[len("sqlite://") :]
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            verdict = con.execute("PRAGMA integrity_check").fetchall()
        finally:
            con.close()
        if verdict != [("ok",)]:
            problems.append(f"{path}: integrity_check says {verdict[:5]}")
    return problems
