"""Seeded hostile requests for the HTTP service and hostile command lines (issue 18), shared by the
fuzz test (``tests/test_fuzz.py``, in ``make test``) and the probe (``tests/bench/probe_service.py``).

Each HTTP case is ``(kind, method, path, kwargs)`` for a ``TestClient`` / ``httpx`` call; each CLI case
``(kind, argv)`` for ``proctex.cli.main``. Every case is bounded (bodies of at most a few hundred KB).
"""

from __future__ import annotations

import json
import random
from typing import Any

ODD_NAMES = ["", ".", "..", "a" * 1500, "a\\b", "a\x00b", "mug/../mug", "%2e%2e", "MUG", "mug ", " mug", "m\u00fcg", "mug.json", "-mug", "mug;rm", "<script>", "mug\nx", "x" * 129]
HUGE = ["9" * 400, "-" + "9" * 400, "1e999", "-1e999", "nan", "NaN", "inf", "-inf", "1e308", "0x10", "", " ", "true", "[]", "{}", "null"]


def _deep(depth: int, kind: str) -> str:
    return ("[" * depth + "]" * depth) if kind == "list" else ('{"a":' * depth + "1" + "}" * depth)


def _json_value(rng: random.Random, depth: int = 0) -> Any:
    pick = rng.randrange(10 if depth < 3 else 6)
    if pick == 0:
        return rng.choice([0, -1, 1, 2**31, 2**63, -(2**63), 10**30, 0.5, -0.0])
    if pick == 1:
        return rng.choice([float("1e308"), 1e-308, 3.5, -7.25])
    if pick == 2:
        return rng.choice(["", "x" * rng.choice([1, 100, 5000]), "\u0000", "\ud7ff", "red brick", "../../etc/passwd"])
    if pick == 3:
        return rng.choice([True, False, None])
    if pick in (4, 5):
        return rng.choice(["radius", "height", "seed", "hue"])
    if pick in (6, 7):
        return [_json_value(rng, depth + 1) for _ in range(rng.randrange(4))]
    return {rng.choice(["params", "seed", "edits", "radius", "height", "group", "hue", "x" * 50]): _json_value(rng, depth + 1) for _ in range(rng.randrange(4))}


def _mesh_bytes(rng: random.Random) -> tuple[str, bytes]:
    suffix = rng.choice([".obj", ".ply", ".stl", ".glb", ".gltf", ".OBJ", ".txt", ".exe", ""])
    pick = rng.randrange(8)
    if pick == 0:
        data = bytes(rng.randrange(256) for _ in range(rng.choice([0, 1, 80, 84, 1000])))
    elif pick == 1:
        n = rng.choice([1, 3, 50])
        data = "".join(f"v {rng.uniform(-1, 1)} {rng.uniform(-1, 1)} {rng.uniform(-1, 1)}\n" for _ in range(n)).encode()
        data += "".join(f"f {rng.randrange(-5, n + 5)} {rng.randrange(1, n + 2)} {rng.choice(['9' * 30, '1', '2', '-1'])}\n" for _ in range(n)).encode()
    elif pick == 2:
        data = b"solid x\nfacet normal 0 0 1\nouter loop\nvertex nan 0 0\nvertex 1 0 0\nvertex 0 1e999 0\nendloop\nendfacet\nendsolid\n"
    elif pick == 3:
        data = b"ply\nformat ascii 1.0\nelement vertex 999999999\nproperty float x\nend_header\n1\n"
    elif pick == 4:
        data = json.dumps({"asset": {"version": "2.0"}, "buffers": [{"uri": "/etc/passwd", "byteLength": 10}]}).encode()
    elif pick == 5:
        data = b"glTF" + bytes(rng.randrange(256) for _ in range(200))
    elif pick == 6:
        data = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n" + b"f 1 2 3\n" * rng.choice([1, 2000])
    else:
        data = ("v 0 0 0\n" * 3 + "f " + " ".join(["1"] * rng.choice([3, 500])) + "\n").encode()
    return f"m{suffix}", data


def http_cases(family: str = "mug", n: int = 200, seed: int = 0) -> list[tuple[str, str, str, dict[str, Any]]]:
    """``n`` seeded hostile requests against ``family`` (plus the fixed ones)."""
    rng = random.Random(seed)
    base = f"/v1/families/{family}"
    cases: list[tuple[str, str, str, dict[str, Any]]] = []
    for name in ODD_NAMES:
        from urllib.parse import quote

        q = quote(name, safe="")
        cases += [("name", "get", f"/v1/families/{q}", {}), ("name", "post", f"/v1/families/{q}/transfer", {"json": {"params": {}}})]
    for h in HUGE:
        cases += [
            ("number", "post", f"{base}/transfer", {"content": ('{"params": {"radius": %s}}' % h).encode(), "headers": {"content-type": "application/json"}}),
            ("number", "post", f"{base}/transfer", {"content": ('{"params": {}, "seed": %s}' % h).encode(), "headers": {"content-type": "application/json"}}),
            ("number", "get", f"{base}/groups/0/texture.png?size={h}", {}),
            ("number", "get", f"{base}/groups/0/texture.png?hue={h}&value={h}", {}),
            ("number", "post", f"{base}/transfer", {"files": {"mesh": ("m.obj", b"v 0 0 0\n")}, "data": {"seed": h}}),
        ]
    for depth in (100, 2000, 20000):
        for kind in ("list", "dict"):
            body = ('{"params": ' + _deep(depth, kind) + "}").encode()
            cases += [
                ("nesting", "post", f"{base}/transfer", {"content": body, "headers": {"content-type": "application/json"}}),
                ("nesting", "post", f"{base}/edits", {"content": body, "headers": {"content-type": "application/json"}}),
            ]
    for ctype in ("text/plain", "application/x-www-form-urlencoded", "application/xml", "multipart/form-data", "application/json; charset=utf-16"):
        cases.append(("content-type", "post", f"{base}/transfer", {"content": b'{"params": {}}', "headers": {"content-type": ctype}}))
    for _ in range(n):
        pick = rng.randrange(4)
        if pick == 0:
            body = json.dumps(_json_value(rng), allow_nan=True).encode()
            cases.append(("json", "post", f"{base}/transfer", {"content": body, "headers": {"content-type": "application/json"}}))
        elif pick == 1:
            fname, data = _mesh_bytes(rng)
            extra = {"data": {"edits": json.dumps(_json_value(rng))}} if rng.random() < 0.3 else {}
            cases.append(("mesh", "post", f"{base}/transfer", {"files": {"mesh": (fname, data)}, **extra}))
        elif pick == 2:
            g = rng.choice(["0", "1", "99", "-1", "body", "x" * 300, "%00"])
            q = "&".join(f"{k}={rng.choice(HUGE + ['10', '0.5', 'red'])}" for k in rng.sample(["size", "hue", "saturation", "value", "prompt", "x"], 2))
            cases.append(("texture", "get", f"{base}/groups/{g}/texture.png?{q}", {}))
        else:
            body = json.dumps(_json_value(rng)).encode()
            cases.append(("edit", "post", f"{base}/edits", {"content": body, "headers": {"content-type": "application/json"}}))
    return cases


def cli_cases(family_dir: str, out_dir: str) -> list[tuple[str, list[str]]]:
    """Hostile command lines against a built family in ``family_dir``, writing under ``out_dir``."""
    o = out_dir.rstrip("/")
    cases: list[tuple[str, list[str]]] = []
    for params in ["[" * 5000, '{"radius": ' + "9" * 400 + "}", '{"radius": 1e999}', '{"nope": 1}', "null", '"x"', "{" * 3, "{}" * 2]:
        cases.append(("params", ["transfer", family_dir, "--params", params, "--out", f"{o}/p.glb"]))
    for out in ["/proc/nope/x.glb", "/", o, f"{o}/x.txt", f"{o}/" + "a" * 300 + ".glb"]:
        cases.append(("out", ["transfer", family_dir, "--params", "{}", "--out", out]))
    for tol in ["nan", "inf", "-1", "0", "1e999"]:
        cases.append(("number", ["segment", "mug", "--tol", tol]))
    for fam in ["/nonexistent", "/", o, "/etc"]:
        cases.append(("family", ["transfer", fam, "--params", "{}", "--out", f"{o}/f.glb"]))
    for mesh in ["/nonexistent.obj", "/etc/passwd", "/dev/null"]:
        cases.append(("mesh", ["segment", mesh]))
    cases.append(("config", ["build", "--model", "mug", "--n-train", "1", "--out", f"{o}/fam1"]))
    cases.append(("config", ["build", "--model", "nosuch", "--out", f"{o}/fam2"]))
    cases.append(("config", ["render", "/nonexistent.glb"]))
    return cases
