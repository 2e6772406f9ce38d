"""The build's one compiled part: the optional fault-round kernel (``src/distnav/_dropround.c``, plain C without
Python.h, loaded with ctypes by ``distnav._dropround``). Everything else is in pyproject.toml.

``optional=True``: where the compiler is missing or fails, pip warns and installs distnav without it; the mixer then
takes its numpy path (the same results bit for bit, slower fault rounds). ``-ffp-contract=off``: no fused
multiply-add, so the kernel rounds every operation as numpy and scipy do.
"""

import sys

from setuptools import Extension, setup

_FLAGS = ["/O2", "/fp:precise"] if sys.platform == "win32" else ["-O3", "-ffp-contract=off", "-fno-fast-math"]

setup(
    ext_modules=[
        Extension(
            "distnav._dropround_c",
            sources=["src/distnav/_dropround.c"],
            extra_compile_args=_FLAGS,
            optional=True,
        )
    ]
)
