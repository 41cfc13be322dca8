"""A test's C code as a cffi module: compiled at test time (out-of-line API mode) into a
temporary directory and imported."""
from __future__ import annotations

import importlib.util
from pathlib import Path


def build(name: str, cdef: str, source: str, sources, include_dirs, tmpdir: Path, define_macros=()):
    """Compile `sources` with `source` (the includes) declaring `cdef`; the imported module."""
    from cffi import FFI

    ffi = FFI()
    ffi.cdef(cdef)
    ffi.set_source(name, source, sources=[str(p) for p in sources], include_dirs=[str(p) for p in include_dirs],
                   define_macros=list(define_macros), extra_compile_args=["-std=c99", "-O1", "-Wall", "-Wextra"])
    path = ffi.compile(tmpdir=str(tmpdir))
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
