"""Build hooks: the C core compiled twice through cffi (host/imulink/core/_build.py), and the
native board (firmware/boards/native, built by firmware/Makefile) installed inside the
package, so that `imulink demo` and `imulink emulate` work from any install."""
import shutil
import subprocess
import tempfile
from pathlib import Path

from setuptools import setup
from setuptools.command.build_ext import build_ext

ROOT = Path(__file__).resolve().parent


class BuildExtAndNativeBoard(build_ext):
    def run(self):
        super().run()
        package_dir = Path(self.get_ext_fullpath("imulink.core._fixed")).parent.parent
        target = package_dir / "firmware" / "native" / "imulink-native"
        with tempfile.TemporaryDirectory() as build:
            subprocess.run(["make", "--no-print-directory", "-C", str(ROOT / "firmware"), "native", f"BUILD={build}"],
                           check=True)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(Path(build) / "native" / "imulink-native", target)


setup(cffi_modules=["host/imulink/core/_build.py:ffi_fixed", "host/imulink/core/_build.py:ffi_float"],
      cmdclass={"build_ext": BuildExtAndNativeBoard})
