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
    floors = {extra: floor(PROJECT["optional-dependencies"][extra], "pyqtgraph") for extra in ("monitor", "test")}
    assert floors["monitor"] == floors["test"]
    installed = version(metadata.version("pyqtgraph"))
    # the declared range admits what a fresh install picks (a release newer than the floor too)
    assert installed >= floors["monitor"]
    [needs] = [r for r in metadata.requires("pyqtgraph") if re.match(r"numpy\s*>=", r)]
    if installed[:2] == floors["monitor"][:2]:
        # the floor release's own metadata: the package's numpy floor must install it
        assert numpy_floor >= version(needs.split(">=", 1)[1])
    else:
        # a newer release may need a newer numpy, which pip then picks: only the floor's claim is ours
        assert version(metadata.version("numpy")) >= version(needs.split(">=", 1)[1])
