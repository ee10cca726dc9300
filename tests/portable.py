"""Float checks that hold on every CPU (issue 30).

numpy's vectorised ``exp``, ``log``, ``arctan2``, ``power`` and friends, BLAS reductions and torch's
kernels take different code paths on CPUs with and without AVX-512, so the last bits of a float
result are a property of the machine, not of the code. What a test may compare exactly is what is
exact by construction: integers (faces, counts, indices), copies, IEEE basic arithmetic on the same
inputs in the same order. Everything else is compared with a tolerance that says how far apart two
CPUs may land.

- :func:`sketch` / :func:`assert_sketch_close`: a compact fingerprint of a float array (signed
  weighted sums with weights from integer hashing, exact on every machine) and its comparison with
  a per-coordinate tolerance carried through the weights. It fails when any coordinate moves by more
  than about ``2 * rel * scale * n`` (``n`` coordinates), and never for ULP-level noise.
- :func:`no_avx512_env`: the environment under which numpy, torch and oneDNN take the paths of a CPU
  without AVX-512, so a developer's AVX-512 machine also runs them (tests/test_portability.py).
- :func:`other_env`: kernels one tier below this CPU's own on any machine (numpy, OpenBLAS, ATen,
  oneDNN, MKL): the environment ``make test`` runs the fast float tests under a second time.
"""

from __future__ import annotations

import os

import numpy as np

#: Fingerprint weights per array.
SKETCH_SIZE = 8
#: Per-coordinate tolerance relative to the array's scale (its largest magnitude; 1 if all zero). The
#: difference between an AVX-512 and an AVX2 machine measured on the built-in models is at most
#: 1.1e-16 absolute on coordinates up to 0.74 (1.5e-16 relative, ~1 ULP): 1e-12 leaves four orders of
#: magnitude for longer chains of transcendental functions, and is still far below anything a change
#: of the code would move (1e-9 and up).
SKETCH_REL = 1e-12

_MIX = (np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB))


def sketch_weights(n: int, k: int = SKETCH_SIZE) -> np.ndarray:
    """``(k, n)`` float64 weights of magnitude in [0.5, 1) with pseudo-random signs, from a
    splitmix64 hash of (row, index) in unsigned integer arithmetic: the same bits on every machine
    and numpy version (no random generator stream involved)."""
    i = np.arange(n, dtype=np.uint64)[None, :]
    j = np.arange(1, k + 1, dtype=np.uint64)[:, None]
    with np.errstate(over="ignore"):
        x = i * np.uint64(0x9E3779B97F4A7C15) + j * np.uint64(0xD1B54A32D192ED03)
        x ^= x >> np.uint64(30)
        x *= _MIX[0]
        x ^= x >> np.uint64(27)
        x *= _MIX[1]
        x ^= x >> np.uint64(31)
    magnitude = 0.5 + 0.5 * ((x >> np.uint64(11)).astype(np.float64) * 2.0**-53)  # exact: 53-bit integers
    sign = np.where((x >> np.uint64(63)) == 1, -1.0, 1.0)
    return sign * magnitude


def sketch(a: np.ndarray) -> dict:
    """Fingerprint of a float array: its shape, its scale and :data:`SKETCH_SIZE` weighted sums of its
    flattened values (:func:`sketch_weights`). JSON-friendly."""
    a = np.asarray(a, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise ValueError("sketch: the array holds NaN or infinite values")
    flat = a.ravel()
    return dict(shape=list(a.shape), scale=float(np.abs(flat).max(initial=0.0)) or 1.0, sums=[float(s) for s in sketch_weights(flat.size) @ flat])


def sketch_mismatch(a: np.ndarray, ref: dict, rel: float = SKETCH_REL) -> str | None:
    """Why ``a`` does not match the fingerprint ``ref`` (:func:`sketch`), or None when it does: the
    shapes must be equal and each weighted sum within ``rel * scale * sum(|w|)``, the most that
    coordinates each off by ``rel * scale`` can move it."""
    a = np.asarray(a, dtype=np.float64)
    if list(a.shape) != list(ref["shape"]):
        return f"shape {list(a.shape)} != {ref['shape']}"
    got = sketch(a)
    w = sketch_weights(a.size)
    tol = rel * ref["scale"] * np.abs(w).sum(axis=1)
    off = np.abs(np.asarray(got["sums"]) - np.asarray(ref["sums"]))
    if np.all(off <= tol):
        return None
    return f"weighted sums off by up to {off.max():.3g} (tolerance {tol.min():.3g}: {rel:g} x scale per coordinate)"


def assert_sketch_close(a: np.ndarray, ref: dict, what: str = "array", rel: float = SKETCH_REL) -> None:
    why = sketch_mismatch(a, ref, rel)
    assert why is None, f"{what}: {why}"


# ------------------------------------------------------------------------------ paths without AVX-512
def _numpy_dispatch() -> tuple[list[str], dict]:
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:  # numpy 1.x
        from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    return list(__cpu_dispatch__), dict(__cpu_features__)


def numpy_avx512_targets() -> list[str]:
    """numpy's dispatch targets that need AVX-512 (``X86_V4``, ``AVX512_*``) in this numpy: the
    names ``NPY_DISABLE_CPU_FEATURES`` accepts differ between numpy 1.x and 2.x."""
    targets, _ = _numpy_dispatch()
    return [t for t in targets if t.startswith("AVX512") or t == "X86_V4"]


def no_avx512_env(base: dict | None = None) -> dict:
    """A copy of ``base`` (default ``os.environ``) under which numpy dispatches no AVX-512 kernel,
    torch's ATen kernels run at AVX2 and oneDNN stops at AVX2 (so bfloat16 is not native and
    ``autocast="auto"`` takes float32, as on such a CPU: :func:`proctex.correspond.corrnet.native_bfloat16`)."""
    env = native_env(base)
    env["NPY_DISABLE_CPU_FEATURES"] = " ".join(numpy_avx512_targets())
    env["ATEN_CPU_CAPABILITY"] = "avx2"
    env["ONEDNN_MAX_CPU_ISA"] = "AVX2"
    return env


#: numpy 1.x names of the dispatch targets an AVX2 CPU adds to the x86-64-v2 baseline (numpy 2.x: ``X86_V3``).
_V3_TARGETS = {"X86_V3", "AVX", "AVX2", "FMA3", "F16C", "AVX2_FMA3"}


def cpu_tier() -> str:
    """``"avx512"``, ``"avx2"``, ``"x86"`` (neither) or the machine name elsewhere (``"aarch64"``),
    from numpy's view of this CPU (its feature flags, which ``NPY_DISABLE_CPU_FEATURES`` leaves alone)."""
    import platform

    _, features = _numpy_dispatch()
    if features.get("AVX512F") or features.get("X86_V4"):
        return "avx512"
    if features.get("AVX2") or features.get("X86_V3"):
        return "avx2"
    machine = platform.machine().lower()
    return "x86" if machine in ("x86_64", "amd64", "i686") else machine


#: The variables :func:`other_env` and :func:`no_avx512_env` set.
KERNEL_VARS = ("NPY_DISABLE_CPU_FEATURES", "ATEN_CPU_CAPABILITY", "ONEDNN_MAX_CPU_ISA", "MKL_ENABLE_INSTRUCTIONS", "OPENBLAS_CORETYPE", "PROCTEX_KERNELS")


def native_env(base: dict | None = None) -> dict:
    """A copy of ``base`` (default ``os.environ``) without the variables that choose kernels
    (:data:`KERNEL_VARS`): this CPU's own kernels, also from inside ``make test``'s second pass."""
    return {k: v for k, v in (os.environ if base is None else base).items() if k not in KERNEL_VARS}


def other_env(base: dict | None = None) -> dict:
    """A copy of ``base`` (default ``os.environ``) under which numpy, OpenBLAS (numpy's and scipy's),
    torch's ATen and oneDNN and MKL take other kernels than they take natively on this CPU, one tier
    down (issue 49): what another user's machine computes.

    - AVX-512 CPU: numpy without its AVX-512 targets, ``ATEN_CPU_CAPABILITY=avx2``, oneDNN and MKL at
      AVX2, ``OPENBLAS_CORETYPE=Haswell`` (an AVX2 machine's kernels);
    - AVX2 CPU: numpy without ``X86_V3`` (its x86-64-v2 baseline loops), ``ATEN_CPU_CAPABILITY=default``,
      oneDNN and MKL at AVX, ``OPENBLAS_CORETYPE=Sandybridge`` (Haswell and Zen are this CPU's own);
    - other CPUs: numpy without any dispatch target beyond its baseline, ATen's default kernels, and
      OpenBLAS's oldest core of the architecture (Prescott on x86, ARMV8 on arm64).

    tests/test_portability.py shows that it changes the last bits of numpy's, BLAS's and torch's results."""
    env = native_env(base)
    targets, features = _numpy_dispatch()
    tier = cpu_tier()
    if tier == "avx512":
        off = numpy_avx512_targets()
        env.update(ATEN_CPU_CAPABILITY="avx2", ONEDNN_MAX_CPU_ISA="AVX2", MKL_ENABLE_INSTRUCTIONS="AVX2", OPENBLAS_CORETYPE="Haswell")
    elif tier == "avx2":
        off = [t for t in targets if t in _V3_TARGETS]
        env.update(ATEN_CPU_CAPABILITY="default", ONEDNN_MAX_CPU_ISA="AVX", MKL_ENABLE_INSTRUCTIONS="AVX", OPENBLAS_CORETYPE="Sandybridge")
    else:
        off = [t for t in targets if features.get(t)]
        env.update(ATEN_CPU_CAPABILITY="default", OPENBLAS_CORETYPE="Prescott" if tier == "x86" else "ARMV8")
    env["NPY_DISABLE_CPU_FEATURES"] = " ".join(off)
    env["PROCTEX_KERNELS"] = f"other ({tier} CPU)"  # tests/floatrecord.py names the run's records by it
    return env


# ---------------------------------------------------------------------------------- files from floats
def glb_mismatch(a: bytes, b: bytes) -> str | None:
    """Why two GLBs made by the same code from the same inputs differ beyond float noise, or None.

    Equal bytes are equal. Otherwise (the same program run with other thread counts or kernels: a
    threaded BLAS reduction sums in another order) both are read back and compared: structure, faces,
    groups and names exactly; positions, UVs and normals within 2e-7 of their scale (float32 in the
    file, so a last-bit change upstream shows as one float32 ULP, 6e-8 relative: the bound leaves
    room for that and still fails on any change of the geometry a user could see); texture, ORM and
    normal-map texels within one level of 255 (a value on a rounding boundary may round either way)."""
    if a == b:
        return None
    from proctex.texture.gltf_read import read_textured_glb

    x, y = read_textured_glb(a), read_textured_glb(b)
    for key in ("faces", "face_group"):
        if not np.array_equal(getattr(x, key), getattr(y, key)):
            return f"{key} differ"
    if x.names != y.names or len(x.textures) != len(y.textures) or len(x.pbr) != len(y.pbr):
        return "materials differ"
    for key in ("vertices", "corner_uv", "corner_normals"):
        u, v = getattr(x, key), getattr(y, key)
        if (u is None) != (v is None) or (u is not None and u.shape != v.shape):
            return f"{key} differ in shape"
        if u is not None:
            scale = max(float(np.abs(u).max(initial=0.0)), 1e-12)
            off = float(np.abs(u - v).max(initial=0.0))
            if off > 2e-7 * scale:  # float32 storage: a few ULPs
                return f"{key} off by {off:.3g} (scale {scale:.3g})"
    images = list(zip(x.textures, y.textures))
    for p, q in zip(x.pbr, y.pbr):
        if (p is None) != (q is None):
            return "PBR maps differ"
        if p is not None:
            images += [(getattr(p, k), getattr(q, k)) for k in vars(p) if isinstance(getattr(p, k), np.ndarray)]
    for i, (u, v) in enumerate(images):
        if u.shape != v.shape:
            return f"image {i} differs in shape"
        if np.abs(u.astype(np.float64) - v.astype(np.float64)).max(initial=0.0) > (1.0 if u.dtype == np.uint8 else 1.0 / 255 + 1e-6):
            return f"image {i} differs by more than one level"
    return None


# ------------------------------------------------------------------------------- the second pass
def other_env_changes(base: dict | None = None) -> dict:
    """What :func:`other_env` sets that differs from ``base`` (default ``os.environ``)."""
    base = dict(os.environ if base is None else base)
    return {k: v for k, v in other_env(base).items() if base.get(k) != v}


def main(argv: list[str] | None = None) -> int:
    """``python -m tests.portable [PYTEST ARGS]``: pytest under :func:`other_env`, saying which
    kernels it changes (``make test`` runs the fast tests marked ``numeric`` this way). Pytest
    replaces this process (``exec``): a signal sent to it reaches pytest."""
    import sys

    args = sys.argv[1:] if argv is None else argv
    changes = other_env_changes()
    shown = {k: v for k, v in changes.items() if k != "PROCTEX_KERNELS"}
    print(f"other kernels than this CPU's own ({cpu_tier()}): " + " ".join(f"{k}={v!r}" for k, v in shown.items()), flush=True)
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, "-m", "pytest", *args], other_env())


if __name__ == "__main__":
    raise SystemExit(main())
