"""Build the native SSI kernels (posecast._native); everything else is in pyproject.toml.

The extension is optional: where no C compiler is at hand the install still succeeds
and the engine serves with the ``onnx`` backend (docs/engine.md). One build runs on
any x86-64: each instruction-set level is compiled in its own file with its own
target pragma and chosen at import time, so no ``-march`` flag is needed.
"""

from setuptools import Extension, setup

SOURCES = [
    "server/native/pc_module.c",
    "server/native/pc_levels.c",
    "server/native/pc_threads.c",
    "server/native/pc_buffers.c",
    "server/native/pc_py_pack.c",
    "server/native/pc_py_ssi.c",
    "server/native/pc_py_out.c",
    "server/native/pc_isa_generic.c",
    "server/native/pc_isa_avx2.c",
    "server/native/pc_isa_avx512.c",
    "server/native/pc_isa_avx512bf16.c",
    "server/native/pc_upper.c",
    "server/native/pc_records.c",
]

setup(
    ext_modules=[
        Extension(
            "posecast._native",
            sources=SOURCES,
            depends=["server/native/pc_module.h", "server/native/pc_kernels.h", "server/native/pc_impl.h",
                     "server/native/pc_upper.h", "server/native/pc_records.h", "server/native/pc_geom.h"],
            include_dirs=["server/native"],
            extra_compile_args=["-O3", "-std=gnu11", "-fno-math-errno", "-Wall", "-Wextra",
                                "-Wno-unused-parameter", "-Wno-missing-field-initializers"],
            libraries=["pthread", "m"],
            optional=True,
        )
    ]
)
