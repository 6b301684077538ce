"""Native engine, compiling and caching: the C compiler, its flags, the on-disk library cache.

The compiled library is cached by a hash of its source, the compiler and its flags and the CPU,
in ``$STABJAX_CACHE_DIR`` (default ``~/.cache/stabjax/native``). The compiler is ``$CC``, else
``cc``, ``gcc`` or ``clang`` on PATH.
"""
from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

from ..base import Unsupported

def compiler() -> str | None:
    """The C compiler to use ($CC, else cc/gcc on PATH), or None."""
    for cand in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if cand and shutil.which(cand):
            return shutil.which(cand)
    return None


@functools.lru_cache(maxsize=4)
def _is_gcc(cc: str | None) -> bool:
    if cc is None:
        return False
    try:
        return "Free Software Foundation" in subprocess.run([cc, "--version"], capture_output=True, text=True).stdout
    except OSError:
        return False


def _flag_sets() -> list[list[str]]:
    base = ["-O3", "-fPIC", "-shared", "-fopenmp-simd", "-fno-math-errno", "-fno-trapping-math", "-std=gnu11"]
    sets = []
    if platform.machine() in ("x86_64", "AMD64"):
        vec = base + ["-march=native", "-mprefer-vector-width=512", "-DSTABJAX_LIBMVEC"]
        if _is_gcc(compiler()):
            # GCC schedules instructions before register allocation only when asked (off on x86):
            # -4% (one thread) to -6% (two) median wall in interleaved pairs, same results (docs/performance.md;
            # N19); -fno-plt calls libmvec through the GOT, without the PLT's extra jump
            sets.append(vec + ["-fschedule-insns", "-fsched-pressure", "-fno-plt"])
        sets.append(vec)
        sets.append(base + ["-march=native"])
    else:
        sets.append(base + ["-mcpu=native"])
    sets.append(base)
    return sets


def _cpu_key() -> str:
    try:
        text = Path("/proc/cpuinfo").read_text()
        lines = [ln for ln in text.splitlines() if ln.startswith(("model name", "flags", "Features"))]
        return "\n".join(sorted(set(lines)))
    except OSError:
        return platform.processor()


def cache_dir() -> Path:
    d = os.environ.get("STABJAX_CACHE_DIR")
    return Path(d) if d else Path.home() / ".cache" / "stabjax" / "native"


_LOAD_LOCK = threading.Lock()


def compile_library(source: str) -> ctypes.CDLL:
    """Compile C ``source`` into a cached shared library with the first flag set the compiler accepts."""
    cc = compiler()
    if cc is None:
        raise Unsupported("no C compiler on PATH (set CC)")
    errors = []
    version = subprocess.run([cc, "--version"], capture_output=True, text=True).stdout.splitlines()[:1]
    for flags in _flag_sets():
        libs = ["-lmvec", "-lm"] if "-DSTABJAX_LIBMVEC" in flags else ["-lm"]
        key = hashlib.sha256("\0".join([source, cc, *version, *flags, *libs, _cpu_key()]).encode()).hexdigest()[:24]
        d = cache_dir()
        so = d / f"stabjax_{key}.so"
        with _LOAD_LOCK:
            if not so.exists():
                d.mkdir(parents=True, exist_ok=True)
                with tempfile.TemporaryDirectory(dir=d) as tmp:
                    c_path = Path(tmp) / "kernel.c"
                    c_path.write_text(source)
                    out = Path(tmp) / "kernel.so"
                    proc = subprocess.run([cc, *flags, str(c_path), "-o", str(out), *libs], capture_output=True, text=True)
                    if proc.returncode != 0:
                        errors.append(f"{' '.join(flags)}: {proc.stderr.strip()[-2000:]}")
                        continue
                    os.replace(out, so)  # atomic: concurrent processes never load a half-written file
            try:
                lib = ctypes.CDLL(str(so))
            except OSError as exc:
                errors.append(f"{' '.join(flags)}: load failed: {exc}")
                continue
        return lib
    raise Unsupported("C compiler failed:\n" + "\n".join(errors))



@functools.lru_cache(maxsize=1)
def available() -> bool:
    """Whether a C compiler builds and loads a small kernel here (checked once per process)."""
    try:
        compile_library("#include <stdint.h>\nint64_t stabjax_run(void *p) { return 0; }\n")
        return True
    except Unsupported:
        return False
