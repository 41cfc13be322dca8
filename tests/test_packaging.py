"""pyproject.toml's constraints are true: an extra installs on the package's own numpy floor
(its packages' metadata as installed here says what they need)."""
from __future__ import annotations

import re
import sys
from importlib import metadata
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

PROJECT = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]


def version(text: str) -> tuple[int, ...]:
    """A release as a tuple to compare, padded to three numbers (1.25 == 1.25.0)."""
    parts = [int(part) for part in re.match(r"\d+(\.\d+)*", text).group(0).split(".")]
    return tuple(parts + [0] * (3 - len(parts)))


def floor(requirements: list[str], name: str) -> tuple[int, ...]:
    """The `>=` version `name` is required at in `requirements`."""
    [found] = [r for r in requirements if re.match(rf"{re.escape(name)}\s*>=", r, re.I)]
    return version(found.split(">=", 1)[1])


def test_the_monitor_extra_installs_on_the_package_s_numpy_floor():
    numpy_floor = floor(PROJECT["dependencies"], "numpy")
    installed = version(metadata.version("pyqtgraph"))
    for extra in ("monitor", "test"):
        # the floor is the version tested here: its metadata is the one read below
        assert floor(PROJECT["optional-dependencies"][extra], "pyqtgraph")[:2] == installed[:2], extra
    [needs] = [r for r in metadata.requires("pyqtgraph") if re.match(r"numpy\s*>=", r)]
    assert numpy_floor >= version(needs.split(">=", 1)[1])
