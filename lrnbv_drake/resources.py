"""Where the shipped models live, and how Drake's parser finds them.

Every model ships in `models/` (a ROS-style package named `lrnbv_drake_models`), so nothing is
fetched at run time; URLs look like `package://lrnbv_drake_models/ur5e/ur5e.urdf`.
"""

from __future__ import annotations

import os
from pathlib import Path

from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant

PACKAGE_NAME = "lrnbv_drake_models"
MODELS_DIR = Path(__file__).resolve().parent.parent / "models"
_NETWORK_ENV = "DRAKE_ALLOW_NETWORK"


def package_url(relative: str) -> str:
    """The `package://` URL of a file under models/."""
    return f"package://{PACKAGE_NAME}/{relative}"


def _add_models_package(parser: Parser) -> Parser:
    """Registers models/ with a parser (idempotent) and returns the parser."""
    package_map = parser.package_map()
    if not package_map.Contains(PACKAGE_NAME):
        package_map.AddPackageXml(str(MODELS_DIR / "package.xml"))
    return parser


def make_parser(plant: MultibodyPlant) -> Parser:
    """A parser that knows models/ and can never download anything.

    Drake's default package map registers the remote `drake_models` package, and refuses even
    to register it when DRAKE_ALLOW_NETWORK excludes `package_map` (as it should be offline).
    We never use that package: the registration is allowed for the constructor only and the
    package is then removed, so nothing can resolve to a download.
    """
    policy = os.environ.get(_NETWORK_ENV)
    if policy is not None and "package_map" not in policy.split(":"):
        os.environ[_NETWORK_ENV] = f"{policy}:package_map" if policy != "none" else "package_map"
        try:
            parser = Parser(plant)
        finally:
            os.environ[_NETWORK_ENV] = policy
    else:
        parser = Parser(plant)
    if parser.package_map().Contains("drake_models"):
        parser.package_map().Remove("drake_models")
    return _add_models_package(parser)
