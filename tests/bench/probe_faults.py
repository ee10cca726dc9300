"""The faults probe of issue 34: hostile clients, disks and neighbours against a small built family
(the service's ingress and FastAPI app in process, small time bounds), one row per case with what it must get
and what it got. ``tests/test_probe_faults.py`` runs it in ``make test``; the README prints its table.

    .venv/bin/python tests/bench/probe_faults.py [--out out/bench/probe_faults.json]

Classes: slow bodies (stalled, lying about their length, trickling, more than the upload slots),
work bounded before it starts (a 2M-face PLY header, an OBJ face of 100,000 corners, a glTF node
chain 1,000 deep, meshes that cannot be served as float32), a replica lost mid-request (a transfer
retried, an edit not), writes on a full disk and over a
tampered texture, two builds of one store, repaired damage, and nonsense numbers on the command line.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import errno
import hashlib
import io
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

LIMITS = dict(body_seconds=3.0, body_idle_seconds=0.5, body_min_rate=200, max_uploads=1, max_faces=200_000)
TOKEN = {"X-ProcTex-Token": "probe-token"}


def build_family(root: Path) -> Path:
    from proctex.build.pipeline import stage_paint
    from proctex.build.pipeline import stage_sample
    from proctex.build.pipeline import stage_template
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore
    from proctex.store.state import write_config

    cfg = BuildConfig.from_dict(dict(model="mug", n_train=2, n_test=0, texture_size=32, prompt="blue ceramic"))
    st = FamilyStore(root / "mug")
    write_config(st, cfg)
    for stage in (stage_sample, stage_template, stage_paint):
        stage(st, cfg, log=lambda *_: None)
    return root / "mug"


def tree(folder: Path) -> str:
    """One digest of every file (lock files aside) and every folder under ``folder``: a failed write
    leaves neither a file nor an empty folder."""
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if p.is_file() and ".lock" not in p.name:
            h.update(str(p.relative_to(folder)).encode() + p.read_bytes())
        elif p.is_dir():
            h.update(str(p.relative_to(folder)).encode() + b"/")
    return h.hexdigest()


def glb_with_index_count(data: bytes, count) -> bytes:
    """A GLB whose first primitive's index accessor says ``count``."""
    import struct

    n = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + n])
    doc["accessors"][doc["meshes"][0]["primitives"][0]["indices"]]["count"] = count
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    out = data[:12] + struct.pack("<I", len(js)) + b"JSON" + js + data[20 + n :]
    return out[:8] + struct.pack("<I", len(out)) + out[12:]


def chain_gltf(depth: int) -> bytes:
    buf = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes()
    nodes = [{"children": [k + 1]} for k in range(depth - 1)] + [{"mesh": 0}]
    return json.dumps(
        {
            "asset": {"version": "2.0"},
            "scenes": [{"nodes": [0]}],
            "nodes": nodes,
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64," + base64.b64encode(buf).decode()}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}],
        }
    ).encode()


def obj_of(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    return ("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in vertices.tolist()) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces.tolist())).encode()


class FullDisk:
    def __init__(self, fs, state):
        self._fs, self._state = fs, state

    def open_output_stream(self, path, *a, **k):
        if self._state.get("full"):
            raise OSError(errno.ENOSPC, "No space left on device", path)
        return self._fs.open_output_stream(path, *a, **k)

    def __getattr__(self, name):
        return getattr(self._fs, name)


async def http_cases(root: Path, rows: list) -> None:
    import httpx

    from proctex.models import get_model
    from proctex.serve.catalog import Catalog
    from proctex.serve.service import Limits
    from workers.http import create_app

    from workers.ingress import call_app, ingress_app

    cat = Catalog(str(root), Limits(**LIMITS), check_every=0, recheck_after=0.3)
    replica = create_app(lambda: cat, edit_token=TOKEN["X-ProcTex-Token"])
    losses = []  # the next calls a replica is lost on: "before" it works, or "after" (the work done, no answer)

    class Lost(RuntimeError):
        pass

    async def forward(request, family):
        loss = losses.pop(0) if losses else None
        if loss == "before":
            raise Lost("replica died")
        answer = await call_app(replica, request)
        if loss == "after":
            raise Lost("replica died")
        return answer

    app = ingress_app(forward, Limits(**LIMITS), is_lost=lambda exc: isinstance(exc, Lost), retry_seconds=5)
    mug = get_model("mug").generate()

    async def stalled(pause=30.0, release=None, rest=b"{}}"):
        yield b'{"params": '
        if release is not None:  # held until the probe lets it go, however loaded the machine
            await release.wait()
        else:
            await asyncio.sleep(pause)
        yield rest

    async def trickle():
        for _ in range(200):
            yield b" "
            await asyncio.sleep(0.05)

    async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://probe", timeout=30) as c:

        async def post(body, headers=None, files=None):
            t = time.monotonic()
            if files is not None:
                r = await c.post("/v1/families/mug/transfer", files=files)
            else:
                r = await c.post("/v1/families/mug/transfer", content=body, headers={"content-type": "application/json", **(headers or {})})
            return r, time.monotonic() - t

        def row(cls, case, expect, r, took, ok_extra=True):
            try:
                is_json = isinstance(r.json(), dict)
            except ValueError:
                is_json = False
            rows.append(
                {"class": cls, "case": case, "expect": expect, "got": r.status_code, "seconds": round(took, 2), "json": is_json, "ok": str(r.status_code) in expect.split("/") and is_json and ok_extra}
            )

        r, t = await post(stalled(), {"content-length": "1000"})
        row("slow bodies", "Content-Length 1000, 10 bytes, then idle", "408", r, t, t < 5)
        r, t = await post(trickle())
        row("slow bodies", "chunked, 20 bytes/s, never ends", "408", r, t, t < 5)
        # Held on an ingress that lets a body idle a minute, until the probe lets them go: with the
        # probe's 0.5 s the holders ended (408) before a loaded machine's health check and transfer
        # had answered (0.68 s; 2.07 s with both cores busy three times over), so the case measured
        # the race, not whether stalled bodies block anyone. What it checks: both answered while all
        # 40 were held (the seconds are reported, not judged: a loaded machine's are no verdict).
        patient = ingress_app(forward, Limits(**{**LIMITS, "body_idle_seconds": 60.0, "body_seconds": 120.0}), is_lost=lambda exc: isinstance(exc, Lost), retry_seconds=5)
        release = asyncio.Event()
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=patient), base_url="http://probe", timeout=120) as held:
            holders = [
                asyncio.create_task(held.post("/v1/families/mug/transfer", content=stalled(release=release, rest=b"}}"), headers={"content-type": "application/json", "content-length": "1000"}))
                for _ in range(40)
            ]
            await asyncio.sleep(0.2)
            t = time.monotonic()
            h = await held.get("/healthz")
            r = await held.post("/v1/families/mug2/transfer", json={"params": {}})
            t = time.monotonic() - t
            still = not any(x.done() for x in holders)
            release.set()
            ended = await asyncio.gather(*holders)
        rows.append(
            {
                "class": "slow bodies",
                "case": f"40 stalled bodies held: health ({h.status_code}) and another family's transfer",
                "expect": "200",
                "got": r.status_code,
                "seconds": round(t, 2),
                "json": False,
                "ok": h.status_code == 200 and r.status_code == 200 and r.content[:4] == b"glTF" and still and {x.status_code for x in ended} == {422},
            }
        )
        big = 100_000  # over Limits.small_body: an upload, with the one upload slot of LIMITS
        holder = asyncio.create_task(post(stalled(pause=1.5), {"content-length": str(big)}))
        await asyncio.sleep(0.2)
        r, t = await post(b" " * big)
        h = await c.get("/healthz")
        row("slow bodies", "a second upload while the one upload slot stalls (health answers: %d)" % h.status_code, "503", r, t, h.status_code == 200 and r.headers.get("retry-after") == "1")
        await holder
        ply = (
            b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\nproperty float y\nproperty float z\n"
            b"element face 2000000\nproperty list uchar int vertex_indices\nend_header\n"
        ) + b"\0" * 1200
        face = b"".join(f"v {k} {k % 7} 0\n".encode() for k in range(100)) + b"f " + b" ".join(str(1 + k % 100).encode() for k in range(100_000))
        for case, name, data, expect in (
            ("PLY header: 2,000,000 faces", "m.ply", ply, "413"),
            ("OBJ face of 100,000 corners", "m.obj", face, "422"),
            ("glTF node chain 1,000 deep", "m.gltf", chain_gltf(1000), "422"),
            ("sofa-sized mug moved 1e9 away", "m.obj", obj_of(mug.vertices + 1e9, mug.faces), "422"),
            ("mug scaled by 1e300", "m.obj", obj_of(mug.vertices * 1e300, mug.faces), "422"),
            ("mug moved 1e3 away (served)", "m.obj", obj_of(mug.vertices + 1e3, mug.faces), "200"),
        ):
            r, t = await post(None, files={"mesh": (name, data)})
            if expect == "200":
                rows.append(
                    {"class": "bounded work", "case": case, "expect": expect, "got": r.status_code, "seconds": round(t, 2), "json": False, "ok": r.status_code == 200 and r.content[:4] == b"glTF"}
                )
            else:
                row("bounded work", case, expect, r, t, t < 5)

        # a replica lost mid-request (Serve's proxy would say a plain-text 500; tests/test_ray.py kills a real one)
        losses[:] = ["after"]
        r, t = await post(b'{"params": {}}')
        rows.append(
            {
                "class": "lost replica",
                "case": "a transfer whose replica died before answering",
                "expect": "200 (retried)",
                "got": r.status_code,
                "seconds": round(t, 2),
                "json": False,
                "ok": r.status_code == 200 and r.content[:4] == b"glTF" and r.headers.get("x-proctex-retried") == "1",
            }
        )
        losses[:] = ["before", "before"]
        r, t = await post(b'{"params": {}}')
        row("lost replica", "a transfer whose retry is lost too", "503", r, t, r.headers.get("retry-after") == "5")
        losses[:] = ["after"]
        t = time.monotonic()
        r = await c.post("/v1/families/mug/edits", json={"group": 0, "hue": 5}, headers=TOKEN)
        undo = await c.delete("/v1/families/mug/edits/last", headers=TOKEN)  # it had landed: undone
        row("lost replica", "an edit whose replica died after storing it (not retried)", "503", r, time.monotonic() - t, undo.status_code == 200 and "not retried" in r.json()["error"])

        # writes
        from proctex.store.layout import FamilyStore, StoreLayout

        fam = root / "mug"
        state = {"full": False}
        real = FamilyStore.__init__

        def init(self, r):
            real(self, r)
            self.fs = FullDisk(self.fs, state)

        FamilyStore.__init__ = init
        try:
            r = await c.post("/v1/families/mug/edits", json={"group": 0, "hue": 10}, headers=TOKEN)
            before = tree(fam)
            state["full"] = True
            t = time.monotonic()
            r = await c.post("/v1/families/mug/edits", json={"group": 0, "hue": 10}, headers=TOKEN)
            row("writes", "an edit on a full disk (family unchanged)", "507", r, time.monotonic() - t, tree(fam) == before)
            t = time.monotonic()
            r = await c.delete("/v1/families/mug/edits/last", headers=TOKEN)
            row("writes", "an undo on a full disk (family unchanged)", "507", r, time.monotonic() - t, tree(fam) == before)
            state["full"] = False
        finally:
            FamilyStore.__init__ = real
        st = FamilyStore(fam)
        g = st.read_json(StoreLayout.PAINT)["groups"][0]
        rel = StoreLayout.texture(0, g["label"])
        good = (fam / rel).read_bytes()
        from proctex.fileio import encode_png
        from proctex.store.template import decode_png

        (fam / rel).write_bytes(encode_png(255 - decode_png(good, rel)))
        t = time.monotonic()
        r = await c.post("/v1/families/mug/edits", json={"group": 0, "hue": 20}, headers=TOKEN)
        row("writes", "an edit over a texture replaced outside ProcTex", "503", r, time.monotonic() - t, len(st.read_json(StoreLayout.PAINT)["edits"]) == 1)
        (fam / rel).write_bytes(good)  # repaired
        await asyncio.sleep(0.4)
        t = time.monotonic()
        r = await c.get("/v1/families/mug")
        row("damage", "the texture put back: served again without a restart", "200", r, time.monotonic() - t)
        assert (await c.get("/v1/families/mug2")).status_code == 200  # served, then its UVs cut short underneath
        uv = root / "mug2" / "template" / "uv.npz"
        whole = uv.read_bytes()
        uv.write_bytes(whole[: len(whole) // 2])
        before = tree(root / "mug2")
        t = time.monotonic()
        r = await c.post("/v1/families/mug2/edits", json={"group": 0, "hue": 10}, headers=TOKEN)
        row("damage", "an edit over a truncated template/uv.npz (family unchanged)", "503", r, time.monotonic() - t, tree(root / "mug2") == before)
        uv.write_bytes(whole)

        # odd paths and values
        from proctex.texture.export import glb_bytes

        for case, path in (
            ("/v1/families/%2e%2e%2f (was a 307, empty)", "/v1/families/%2e%2e%2f"),
            ("textures/0.normal.orm.png (served the normal map)", "/v1/families/mug/textures/0.normal.orm.png"),
        ):
            t = time.monotonic()
            r = await c.get(path)
            row("odd input", case, "404", r, time.monotonic() - t)
        r, t = await post(b'{"params": {}, "seed": true}')
        row("odd input", '"seed": true (was taken as 1)', "422", r, t)
        glb = glb_bytes(mug.vertices, mug.faces, np.zeros((len(mug.faces), 3, 2)), np.zeros(len(mug.faces), np.int64), [np.zeros((8, 8, 3), np.uint8)])
        r, t = await post(None, files={"mesh": ("m.glb", glb_with_index_count(glb, -3))})
        row("odd input", "a GLB whose index accessor says count -3 (a triangle was dropped, 200)", "422", r, t)

    # one client's stalled bodies against another client's transfer (issue 54)
    fair = ingress_app(forward, Limits(**{**LIMITS, "body_idle_seconds": 60.0, "body_seconds": 120.0}), is_lost=lambda exc: isinstance(exc, Lost), retry_seconds=5)
    release = asyncio.Event()

    def peer(address):
        return httpx.AsyncClient(transport=httpx.ASGITransport(app=fair, client=(address, 40000)), base_url="http://probe", timeout=120)

    async with peer("192.0.2.1") as bad, peer("192.0.2.2") as good:
        holders = [
            asyncio.create_task(bad.post("/v1/families/mug/transfer", content=stalled(release=release, rest=b"}}"), headers={"content-type": "application/json", "content-length": "1000"}))
            for _ in range(260)
        ]
        share = Limits().client_small_bodies
        deadline = time.monotonic() + 60
        while sum(h.done() for h in holders) < 260 - share and time.monotonic() < deadline:
            await asyncio.sleep(0.1)
        t = time.monotonic()
        r = await good.post("/v1/families/mug2/transfer", json={"params": {}})
        t = time.monotonic() - t
        refused = [h.result() for h in holders if h.done()]
        release.set()
        await asyncio.gather(*holders)
    rows.append(
        {
            "class": "fairness",
            "case": f"260 stalled bodies from one client ({len(refused)} over its share of {share}: 429) and another client's transfer",
            "expect": "200",
            "got": r.status_code,
            "seconds": round(t, 2),
            "json": False,
            "ok": r.status_code == 200 and r.content[:4] == b"glTF" and len(refused) == 260 - share and {x.status_code for x in refused} == {429},
        }
    )

    # looks under their limits (issue 54): over the time budget, over the texels; nothing written
    for case, limits, expect in (("a look past its time budget (look_seconds 1e-6)", {"look_seconds": 1e-6}, "422"), ("a look over its texels (look_texels 1000)", {"look_texels": 1000}, "413")):
        cat2 = Catalog(str(root), Limits(**{**LIMITS, **limits}), check_every=0)
        app2 = create_app(lambda cat2=cat2: cat2, edit_token=TOKEN["X-ProcTex-Token"])
        before = tree(root / "mug2")
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app2), base_url="http://probe", timeout=60) as c2:
            t = time.monotonic()
            r = await c2.post("/v1/families/mug2/looks", json={"name": "probe", "prompt": "red oak"}, headers=TOKEN)
        row("looks", case + ", nothing written", expect, r, time.monotonic() - t, tree(root / "mug2") == before)


def store_cases(root: Path, rows: list) -> None:
    from proctex.cli import main

    fam = root / "mug"
    hold = (
        "import sys, time\nfrom proctex.store.layout import FamilyStore\nfrom proctex.store.locks import build_lock\n"
        "with build_lock(FamilyStore(sys.argv[1]), 'a build'):\n    print('held', flush=True)\n    time.sleep(60)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", hold, str(fam)], stdout=subprocess.PIPE, text=True)
    try:
        proc.stdout.readline()
        err = io.StringIO()
        t = time.monotonic()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(["build", "--model", "mug", "--prompt", "red", "--out", str(fam), "--n-train", "2", "--n-test", "0"])
        rows.append(
            {
                "class": "builds",
                "case": "a second build of a store being built",
                "expect": "exit 2",
                "got": f"exit {code}",
                "seconds": round(time.monotonic() - t, 2),
                "json": False,
                "ok": code == 2 and "held by a build" in err.getvalue(),
            }
        )
    finally:
        proc.kill()
        proc.wait()
    before = tree(fam)
    for case, argv in (
        ("transfer --bake -5", ["transfer", str(fam), "--params", "{}", "--out", str(root / "x.glb"), "--bake", "-5"]),
        ("transfer --bake 100000", ["transfer", str(fam), "--params", "{}", "--out", str(root / "x.glb"), "--bake", "100000"]),
        ("transfer --seed -1", ["transfer", str(fam), "--params", "{}", "--out", str(root / "x.glb"), "--seed", "-1"]),
        ("edit --logo L --size 1e9,1e9", ["edit", str(fam), "--group", "0", "--logo", str(root / "logo.png"), "--size", "1e9,1e9"]),
    ):
        t = time.monotonic()
        with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
            code = main(argv)
        rows.append(
            {
                "class": "nonsense numbers",
                "case": case,
                "expect": "exit 2",
                "got": f"exit {code}",
                "seconds": round(time.monotonic() - t, 2),
                "json": False,
                "ok": code == 2 and tree(fam) == before and not (root / "x.glb").exists(),
            }
        )
    # one set of bounds: what HTTP refuses, the command line refuses before any work (issue 54)
    huge = root / "huge.json"
    huge.write_text(json.dumps({str(k): "oak" for k in range(100_000)}))
    for case, argv in (
        ("look add --prompt of 201 characters", ["look", "add", str(fam), "big", "--prompt", "x" * 201]),
        ("look add --group-prompts of 1.5 MB", ["look", "add", str(fam), "big", "--prompt", "oak", "--group-prompts", str(huge)]),
    ):
        t = time.monotonic()
        with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
            code = main(argv)
        rows.append({"class": "bounds", "case": case, "expect": "exit 2", "got": f"exit {code}", "seconds": round(time.monotonic() - t, 2), "json": False, "ok": code == 2 and tree(fam) == before})
    spec = root / "spec.json"
    spec.write_text(json.dumps({"nope": [0, 1]}))
    out = root / "refused"
    t = time.monotonic()
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        code = main(["build", "--model", "mug", "--prompt", "red", "--out", str(out), "--n-train", "2", "--n-test", "0", "--params-spec", str(spec)])
    rows.append(
        {
            "class": "bounds",
            "case": "a build refused for its --params-spec (left family.json and locks)",
            "expect": "exit 2, no --out",
            "got": f"exit {code}" + ("" if out.exists() else ", no --out"),
            "seconds": round(time.monotonic() - t, 2),
            "json": False,
            "ok": code == 2 and not out.exists(),
        }
    )
    # units: the mug uploaded in other units takes the same UVs (issue 54)
    from proctex.models import get_model
    from proctex.serve.service import FamilyService
    from proctex.store.layout import FamilyStore

    svc = FamilyService(FamilyStore(root / "mug2"))
    mug = get_model("mug").generate({"radius": 0.045, "height": 0.11})
    t = time.monotonic()
    uvs = {s: svc.textured(svc.shape_from_mesh(obj_of(mug.vertices * s, mug.faces), "m.obj"))[0].result.corner_uv for s in (1.0, 1e-6, 1e3, 1e6)}
    moved = max(float(np.abs(uvs[s] - uvs[1.0]).max()) for s in (1e-6, 1e3, 1e6))
    rows.append(
        {
            "class": "units",
            "case": "the mug uploaded in mm, um or km: UVs moved at most",
            "expect": "<= 1e-5",
            "got": f"{moved:.1e}",
            "seconds": round(time.monotonic() - t, 2),
            "json": False,
            "ok": moved <= 1e-5,
        }
    )
    # files honour the umask
    import os

    from proctex.fileio import current_umask

    t = time.monotonic()
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        code = main(["transfer", str(fam), "--params", "{}", "--out", str(root / "mode.glb")])
    mode = os.stat(root / "mode.glb").st_mode & 0o777 if code == 0 else 0
    rows.append(
        {
            "class": "files",
            "case": f"a transfer's GLB under umask {current_umask():03o} (was 600)",
            "expect": f"mode {0o666 & ~current_umask():o}",
            "got": f"mode {mode:o}",
            "seconds": round(time.monotonic() - t, 2),
            "json": False,
            "ok": code == 0 and mode == 0o666 & ~current_umask(),
        }
    )


def run(root: Path) -> list[dict]:
    from proctex.fileio import encode_png

    build_family(root)
    shutil.copytree(root / "mug", root / "mug2")  # another family, for requests beside the hostile ones
    (root / "logo.png").write_bytes(encode_png(np.zeros((8, 8, 3), np.uint8)))
    rows: list[dict] = []
    asyncio.run(http_cases(root, rows))
    shutil.rmtree(root / "mug" / "template" / "edits", ignore_errors=True)
    store_cases(root, rows)
    return rows


def table(rows: list[dict]) -> str:
    lines = ["| class | case | must get | got | s | |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['class']} | {r['case']} | {r['expect']} | {r['got']} | {r['seconds']} | {'ok' if r['ok'] else 'FAIL'} |" for r in rows]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench/probe_faults.json")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        rows = run(Path(tmp))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(rows, indent=1))
    print(table(rows))
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
