"""Build hook: compiles the C core twice through cffi (see host/imulink/_build_core.py)."""
from setuptools import setup

setup(cffi_modules=["host/imulink/_build_core.py:ffi_fixed", "host/imulink/_build_core.py:ffi_float"])
