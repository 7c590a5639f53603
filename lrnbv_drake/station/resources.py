"""Where the shipped models live, and how Drake's parser finds them.

Every model ships in `models/` (a ROS-style package named `lrnbv_drake_models`), so nothing is
fetched at run time; URLs look like `package://lrnbv_drake_models/ur5e/ur5e.urdf`.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.planning import RobotDiagramBuilder

PACKAGE_NAME = "lrnbv_drake_models"
MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
_NETWORK_ENV = "DRAKE_ALLOW_NETWORK"


def package_url(relative: str) -> str:
    """The `package://` URL of a file under models/."""
    return f"package://{PACKAGE_NAME}/{relative}"


def resolve_url(url: str) -> str:
    """A file path for a `package://` URL (through Drake's package map, offline) or a path
    given as it is."""
    if not url.startswith("package://"):
        return url
    with _drake_models_registration_allowed():
        parser = _offline(Parser(MultibodyPlant(time_step=0.0)))
    return parser.package_map().ResolveUrl(url)


def _add_models_package(parser: Parser) -> Parser:
    """Registers models/ with a parser (idempotent) and returns the parser."""
    package_map = parser.package_map()
    if not package_map.Contains(PACKAGE_NAME):
        package_map.AddPackageXml(str(MODELS_DIR / "package.xml"))
    return parser


@contextlib.contextmanager
def _drake_models_registration_allowed() -> Iterator[None]:
    """Lets Drake register (never fetch) its remote `drake_models` package while offline.

    Drake's default package map registers `drake_models`, and refuses even to register it when
    DRAKE_ALLOW_NETWORK excludes `package_map`, which is right for an offline cell. Every
    parser made here removes that package at once, so nothing can resolve to a download.
    """
    policy = os.environ.get(_NETWORK_ENV)
    if policy is None or "package_map" in policy.split(":"):
        yield
        return
    os.environ[_NETWORK_ENV] = f"{policy}:package_map" if policy != "none" else "package_map"
    try:
        yield
    finally:
        os.environ[_NETWORK_ENV] = policy


def _offline(parser: Parser) -> Parser:
    if parser.package_map().Contains("drake_models"):
        parser.package_map().Remove("drake_models")
    return _add_models_package(parser)


def make_parser(plant: MultibodyPlant) -> Parser:
    """A parser that knows models/ and can never download anything."""
    with _drake_models_registration_allowed():
        return _offline(Parser(plant))


def make_robot_diagram_builder(time_step: float = 0.0) -> RobotDiagramBuilder:
    """A RobotDiagramBuilder whose parser knows models/ and can never download anything."""
    with _drake_models_registration_allowed():
        builder = RobotDiagramBuilder(time_step=time_step)
    _offline(builder.parser())
    return builder
